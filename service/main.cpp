// spokemesh-server: the meshing service (gRPC + REST) over a durable point-set store.
//
// Exit codes: 0 after a clean shutdown (SIGTERM/SIGINT), 2 bad flags or configuration,
// 1 failure to start.
#include <malloc.h>

#include <CLI/CLI.hpp>
#include <iostream>

#include "server.hpp"

int main(int argc, char** argv) {
  // The memory budget counts what the server holds; for the process's RSS to follow
  // it, freed memory must go back to the system. glibc's default raises its mmap
  // threshold after each large free (to 32 MB), after which large buffers (point
  // sets, trees, request bodies) come from arenas that never shrink; and each thread
  // may get its own arena. A fixed 64 KiB threshold maps and unmaps every buffer of
  // a point set, tree, cache or stream window (small sets' arrays too: in arenas,
  // thousands of them fragment the heap by tens of MB over a soak run), and a few
  // arenas bound fragmentation across many request threads.
  ::mallopt(M_MMAP_THRESHOLD, 64 << 10);
  ::mallopt(M_TRIM_THRESHOLD, 4 << 20);
  ::mallopt(M_ARENA_MAX, 4);
  CLI::App app{
      "spokemesh-server: exact Delaunay/Voronoi meshing service (gRPC and REST).\n"
      "Point sets are uploaded once, stored durably in --data-dir, and queried per seed."};
  spokemesh::service::ServerFlags flags;
  spokemesh::service::add_server_flags(app, flags);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }
  auto config = spokemesh::service::make_config(flags);
  if (!config.is_ok()) {
    std::cerr << "spokemesh-server: " << config.status().message() << "\n";
    return 2;
  }
  return spokemesh::service::run_server(config.value());
}
