// The data directory: what spokemesh-server's replicas and `spokemesh-mpi store`
// keep in it, under which names, and the one rule by which anything is put there
// (docs/service.md, "Files").
//
//   <dir>/<id>.points          a point set: 12-byte header, coordinates, extras; <id> is
//                              the SHA-256 of those bytes (64 lowercase hex digits)
//   <dir>/<id>.name            its display name (absent: none)
//   <dir>/<id>.owner-<hex>     a tenant's ownership mark (auth.hpp)
//   <dir>/pieces/<id>/         a set kept as pieces (pieces.hpp): manifest, owners, <p>.piece
//   <dir>/.tmp-*               files and directories being written (never read)
//
// The commit rule: bytes are written under a temporary name in the directory they
// go to, fsynced, then moved into place (renamed, or linked when an existing name must
// not be replaced), then that directory is fsynced. A reader sees a whole file or
// directory or none; once the commit returns, it survives a crash of the machine.
// Every writer of a set's name writes the same bytes (names are content hashes), so
// losing a race to another writer is success.
//
// Errors are errno values (0: done) so that each caller words them for its users (the
// server never names its paths to clients; spokemesh-mpi does).
//
// Thread safety: functions are reentrant.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

namespace spokemesh::data_dir {

// A set's id: 64 lowercase hex digits (the SHA-256 of its file's bytes).
bool is_set_id(std::string_view id);
// <dir>/<id>.points (its name in dir: set_file_name); and the set's id when `name` is
// such a file's name, else "".
std::string set_file(const std::string& dir, const std::string& id);
std::string set_file_name(const std::string& id);
std::string set_id_of_file_name(std::string_view name);
// <dir>/<id>.name: the display name; <dir>/<id>.owner-<tenant in hex>: a tenant's mark.
std::string name_file(const std::string& dir, const std::string& id);
std::string owner_file(const std::string& dir, const std::string& id, std::string_view tenant);
// <dir>/pieces/<id> (a layout directory), and in a layout directory (the set's, or
// the temporary one it is written in): manifest, owners, <piece>.piece
std::string pieces_dir(const std::string& dir, const std::string& id);
std::string manifest_file(const std::string& layout_dir);
std::string owners_file(const std::string& layout_dir);
std::string piece_file(const std::string& layout_dir, std::uint32_t piece);
// A fresh temporary name in `dir`: <dir>/.tmp-<tag>-<pid>-<counter>-<random>.
std::string temp_name(const std::string& dir, std::string_view tag = "w");
// Removes temporaries (files in <dir>, directories in <dir>/pieces) older than
// `seconds`: left by a writer that died. Younger ones may be another writer's, now.
void remove_stale_temporaries(const std::string& dir, long seconds);

// fsync of a file or a directory by path.
int sync(const std::string& path);
// Writes all of `bytes` to an open descriptor (retrying short writes and EINTR).
int write_all(int fd, const char* bytes, std::size_t size);

enum class Move {
  kReplace,    // rename over whatever is there
  kExclusive,  // link: EEXIST (and the temporary removed) when `final_path` exists
};
// The commit of a written and fsynced temporary file: moved to `final_path`, the
// directory holding it fsynced. The temporary is gone afterwards, whatever the result.
int commit_file(const std::string& temp, const std::string& final_path, Move move = Move::kReplace);
// The commit of a directory whose files are committed: the directory fsynced, renamed
// to `final_dir`, its parent fsynced. EEXIST when `final_dir` exists (another writer
// put the same layout first: the caller removes `temp_dir`).
int commit_directory(const std::string& temp_dir, const std::string& final_dir);
// A whole file written by the rule: a temporary beside it, fsynced, committed.
int write_file(const std::string& path, std::string_view bytes, Move move = Move::kReplace);

}  // namespace spokemesh::data_dir
