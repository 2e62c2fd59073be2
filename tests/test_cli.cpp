// The spokemesh command line as users run it: a real process on real files.
#include <sys/wait.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <sstream>

#include "support.hpp"

namespace {

namespace fs = std::filesystem;

struct Outcome {
  int code = -1;
  std::string out, err;
};

std::string slurp(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

class Cli : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::path(::testing::TempDir()) /
           ("cli-" + std::string(::testing::UnitTest::GetInstance()->current_test_info()->name()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  std::string path(const std::string& name) const { return (dir_ / name).string(); }
  std::string write(const std::string& name, const std::string& text) const {
    std::ofstream(path(name)) << text;
    return path(name);
  }
  // `env`: NAME=value assignments for the CLI's environment, if any.
  Outcome run(const std::string& args, const std::string& env = "") const {
    const std::string out = path(".run-1"), err = path(".run-2");
    const std::string cmd =
        "env " + env + " " + std::string(SPOKEMESH_CLI) + " " + args + " >" + out + " 2>" + err + " </dev/null";
    const int status = std::system(cmd.c_str());
    return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, slurp(out), slurp(err)};
  }
  std::string points(int d, std::size_t n, std::uint64_t seed) const {
    const auto c = spokemesh::testing::uniform_points(d, n, seed);
    std::ostringstream s;
    s.precision(17);
    for (std::size_t i = 0; i < n; ++i) {
      for (int k = 0; k < d; ++k) s << c[i * d + k] << (k + 1 == d ? "\n" : " ");
    }
    return write("pts" + std::to_string(d) + ".txt", s.str());
  }
  // Output directory holds only the named files (no temporary left behind).
  std::vector<std::string> listing() const {
    std::vector<std::string> names;
    for (const auto& e : fs::directory_iterator(dir_)) names.push_back(e.path().filename().string());
    std::sort(names.begin(), names.end());
    return names;
  }

  fs::path dir_;
};

TEST_F(Cli, HelpForEveryCommand) {
  EXPECT_EQ(run("--help").code, 0);
  for (const char* cmd : {"mesh", "star", "neighbors", "cell", "check"}) {
    const Outcome r = run(std::string(cmd) + " --help");
    EXPECT_EQ(r.code, 0) << cmd;
    EXPECT_NE(r.out.find("INPUT"), std::string::npos) << cmd;
  }
  EXPECT_EQ(run("").code, 2);
  EXPECT_EQ(run("frobnicate").code, 2);
  EXPECT_EQ(run("mesh").code, 2);
}

TEST_F(Cli, MeshWritesEveryFormatAndCheckAcceptsIt) {
  const std::string in = points(2, 500, 1);
  for (const char* ext : {"simplices", "txt", "npy", "vtu", "msh", "svg"}) {
    const Outcome r = run("mesh " + in + " -o " + path(std::string("m.") + ext) + " --threads 2");
    ASSERT_EQ(r.code, 0) << ext << ": " << r.err;
    EXPECT_NE(r.err.find("simplices/s"), std::string::npos) << "summary line: " << r.err;
    EXPECT_NE(r.err.find("MB in triangulations"), std::string::npos) << "summary line: " << r.err;
    EXPECT_NE(r.err.find("insertions per point"), std::string::npos) << "summary line: " << r.err;
  }
  EXPECT_EQ(slurp(path("m.simplices")), slurp(path("m.txt")));
  EXPECT_NE(slurp(path("m.vtu")).find("NumberOfCells"), std::string::npos);
  EXPECT_EQ(slurp(path("m.msh")).rfind("$MeshFormat\n2.2 0 8\n", 0), 0u);
  const Outcome check = run("check " + in + " " + path("m.npy"));
  EXPECT_EQ(check.code, 0) << check.out;
  EXPECT_NE(check.out.find("valid"), std::string::npos);
  EXPECT_EQ(run("mesh -q " + in + " -o " + path("q.simplices")).err, "");
  // The star walk's sweep: the same bytes, and its own summary.
  const Outcome stars = run("mesh " + in + " -o " + path("s.simplices") + " --engine stars");
  ASSERT_EQ(stars.code, 0) << stars.err;
  EXPECT_NE(stars.err.find("MB shared"), std::string::npos) << "summary line: " << stars.err;
  EXPECT_EQ(slurp(path("s.simplices")), slurp(path("m.simplices")));
}

TEST_F(Cli, OutputIsTheSameAcrossThreadsAndSeedRangesUniteToIt) {
  const std::string in = points(3, 400, 2);
  ASSERT_EQ(run("mesh -q " + in + " -o " + path("a.simplices") + " --threads 1").code, 0);
  ASSERT_EQ(run("mesh -q " + in + " -o " + path("b.simplices") + " --threads 2 --random-seed 77").code, 0);
  ASSERT_EQ(run("mesh -q " + in + " -o " + path("c1.simplices") + " --seeds 0:150").code, 0);
  ASSERT_EQ(run("mesh -q " + in + " -o " + path("c2.simplices") + " --seeds 150:400").code, 0);
  const std::string whole = slurp(path("a.simplices"));
  EXPECT_EQ(slurp(path("b.simplices")), whole);
  // Each range in its own sweep order: the same rows, each once.
  const auto sorted_lines = [](const std::string& text) {
    std::vector<std::string> lines;
    std::istringstream stream(text);
    for (std::string line; std::getline(stream, line);) lines.push_back(line);
    std::sort(lines.begin(), lines.end());
    return lines;
  };
  EXPECT_EQ(sorted_lines(slurp(path("c1.simplices")) + slurp(path("c2.simplices"))), sorted_lines(whole));
}

TEST_F(Cli, CheckRejectsACorruptedMesh) {
  const std::string in = points(2, 300, 3);
  ASSERT_EQ(run("mesh -q " + in + " -o " + path("m.simplices")).code, 0);
  std::string mesh = slurp(path("m.simplices"));
  mesh.erase(0, mesh.find('\n') + 1);  // drop the first simplex
  write("broken.simplices", mesh);
  const Outcome r = run("check " + in + " " + path("broken.simplices"));
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("INVALID"), std::string::npos) << r.out;
}

TEST_F(Cli, StarNeighborsAndCell) {
  const std::string in = write("grid.txt", "0 0\n1 0\n2 0\n0 1\n1 1\n2 1\n0 2\n1 2\n2 2\n");
  const Outcome star = run("star " + in + " --seed 4");
  ASSERT_EQ(star.code, 0) << star.err;
  EXPECT_EQ(std::count(star.out.begin(), star.out.end(), '\n'), 6)
      << "the centre of a 3x3 grid: 4 squares, two of them split through the centre by the perturbation:\n"
      << star.out;
  const Outcome nb = run("neighbors " + in + " --seed 4");
  ASSERT_EQ(nb.code, 0);
  const Outcome cell = run("cell " + in + " --seed 4");
  ASSERT_EQ(cell.code, 0);
  EXPECT_NE(cell.out.find("bounded yes"), std::string::npos) << cell.out;
  EXPECT_NE(cell.out.find("volume 1\n"), std::string::npos) << cell.out;
  const Outcome json = run("cell " + in + " --seed 0 --json");
  ASSERT_EQ(json.code, 0);
  EXPECT_NE(json.out.find("\"bounded\": false"), std::string::npos) << json.out;
}

TEST_F(Cli, WeightsAndRadiiGiveTheRegularTriangulation) {
  // The centre of a 3x3 grid with weight -2 (the others 0) lies above the lifted
  // plane of its four edge neighbours (height 1 + w): hidden, in no simplex.
  const std::string in = write("grid.txt", "0 0\n1 0\n2 0\n0 1\n1 1\n2 1\n0 2\n1 2\n2 2\n");
  const std::string w = write("w.txt", "0\n0\n0\n0\n-2\n0\n0\n0\n0\n");
  const Outcome star = run("star " + in + " --seed 4 --weights " + w);
  ASSERT_EQ(star.code, 0) << star.err;
  EXPECT_EQ(star.out, "");
  EXPECT_NE(star.err.find("seed 4 is hidden"), std::string::npos) << star.err;
  const Outcome nb = run("neighbors " + in + " --seed 1 --weights " + w);
  ASSERT_EQ(nb.code, 0) << nb.err;
  EXPECT_EQ(nb.out.find("4\n"), std::string::npos) << "a hidden point is no one's neighbour:\n" << nb.out;
  const Outcome mesh = run("mesh " + in + " --weights " + w + " -o " + path("m.txt"));
  ASSERT_EQ(mesh.code, 0) << mesh.err;
  EXPECT_NE(mesh.err.find("1 of 9 points hidden"), std::string::npos) << mesh.err;
  EXPECT_EQ(slurp(path("m.txt")).find(" 4"), std::string::npos) << slurp(path("m.txt"));

  // --radii r is --weights r^2; equal weights are the Delaunay mesh, byte for byte.
  const std::string pts = points(3, 400, 7);
  std::ostringstream radii, squares, equal;
  radii.precision(17);
  squares.precision(17);
  for (int i = 0; i < 400; ++i) {
    const double r = 0.01 * (i % 7) + 0.5 / 64;  // squares are exact
    radii << r << "\n";
    squares << r * r << "\n";
    equal << "0.125\n";
  }
  ASSERT_EQ(run("mesh " + pts + " --radii " + write("r.txt", radii.str()) + " -o " + path("r.npy")).code, 0);
  ASSERT_EQ(run("mesh " + pts + " --weights " + write("s.txt", squares.str()) + " -o " + path("s.npy")).code, 0);
  EXPECT_EQ(slurp(path("r.npy")), slurp(path("s.npy")));
  ASSERT_EQ(run("mesh " + pts + " --weights " + write("e.txt", equal.str()) + " -o " + path("e.npy")).code, 0);
  ASSERT_EQ(run("mesh " + pts + " -o " + path("plain.npy")).code, 0);
  EXPECT_EQ(slurp(path("e.npy")), slurp(path("plain.npy")));
  const Outcome graph = run("graph " + pts + " --weights " + path("s.txt") + " -o " + path("g.txt"));
  EXPECT_EQ(graph.code, 0) << graph.err;

  // Bad weights: one clear line naming the file and the line or count, exit 2, no output.
  struct Bad {
    std::string args, needle;
  };
  const std::vector<Bad> bad = {
      {"mesh " + in + " --weights " + write("nan.txt", "0\n0\nnan\n0\n0\n0\n0\n0\n0\n") + " -o " + path("x.npy"),
       "nan.txt:3"},
      {"mesh " + in + " --weights " + write("short.txt", "0\n0\n") + " -o " + path("x.npy"), "9"},
      {"mesh " + in + " --radii " + write("neg.txt", "1\n1\n-1\n1\n1\n1\n1\n1\n1\n") + " -o " + path("x.npy"),
       "neg.txt:3"},
      {"mesh " + in + " --weights " + w + " --radii " + w + " -o " + path("x.npy"), "excludes"},
      {"graph " + in + " --weights " + w + " --approx -o " + path("x.npy"), "exact engine"},
      {"mesh " + in + " --weights " + w + " --merge-duplicates -o " + path("x.npy"), "--merge-duplicates"},
      {"mesh " + in + " --weights " + w + " --engine triangulations -o " + path("x.npy"), "--engine stars"},
      {"mesh " + in + " --engine quadtree -o " + path("x.npy"), "--engine"},
  };
  for (const Bad& b : bad) {
    const Outcome o = run(b.args);
    EXPECT_EQ(o.code, 2) << b.args << "\n" << o.err;
    EXPECT_NE(o.err.find(b.needle), std::string::npos) << b.args << "\n" << o.err;
    EXPECT_FALSE(fs::exists(path("x.npy"))) << b.args;
  }
}

TEST_F(Cli, PeriodicMeshWritesOffsets) {
  // A 4x4 integer grid on the torus [0, 4)^2: 32 triangles (2n), each vertex with its offset.
  std::string grid;
  for (int y = 0; y < 4; ++y) {
    for (int x = 0; x < 4; ++x) grid += std::to_string(x) + " " + std::to_string(y) + "\n";
  }
  const std::string in = write("grid.txt", grid);
  const Outcome text = run("mesh " + in + " --periodic 0,0,4,4 -o " + path("t.txt"));
  ASSERT_EQ(text.code, 0) << text.err;
  EXPECT_NE(text.err.find("16 points, 32 simplices"), std::string::npos) << text.err;
  std::istringstream lines(slurp(path("t.txt")));
  std::string line;
  std::getline(lines, line);
  EXPECT_EQ(line.rfind("# periodic mesh", 0), 0u) << line;
  int rows = 0, wrapped = 0;
  while (std::getline(lines, line)) {
    std::istringstream row(line);
    std::vector<long> v((std::istream_iterator<long>(row)), std::istream_iterator<long>());
    ASSERT_EQ(v.size(), 9u) << line;  // 3 indices, 3 x 2 offsets
    EXPECT_EQ(v[3], 0);
    EXPECT_EQ(v[4], 0);  // the owner at offset 0
    wrapped += (v[5] | v[6] | v[7] | v[8]) != 0 ? 1 : 0;
    ++rows;
  }
  EXPECT_EQ(rows, 32);
  EXPECT_GT(wrapped, 0);
  // .npz: the same rows, and the same bytes for any thread count.
  const std::string pts = points(3, 500, 3);
  ASSERT_EQ(run("mesh " + pts + " --periodic 0,0,0,1,1,1 --threads 1 -o " + path("a.npz")).code, 0);
  ASSERT_EQ(run("mesh " + pts + " --periodic 0,0,0,1,1,1 --threads 2 -q -o " + path("b.npz")).code, 0);
  EXPECT_EQ(slurp(path("a.npz")), slurp(path("b.npz")));
  EXPECT_NE(slurp(path("a.npz")).find("offsets.npy"), std::string::npos);

  // --seeds: the simplices those points own; two ranges are the whole torus.
  ASSERT_EQ(run("mesh " + in + " --periodic 0,0,4,4 --seeds 0:7 -q -o " + path("s1.txt")).code, 0);
  ASSERT_EQ(run("mesh " + in + " --periodic 0,0,4,4 --seeds 7:16 -q -o " + path("s2.txt")).code, 0);
  auto body_rows = [&](const std::string& file) {
    std::multiset<std::string> out;
    std::istringstream in_lines(slurp(path(file)));
    std::string l;
    while (std::getline(in_lines, l)) {
      if (l.rfind("#", 0) != 0) out.insert(l);
    }
    return out;
  };
  std::multiset<std::string> parts = body_rows("s1.txt");
  for (const std::string& r : body_rows("s2.txt")) parts.insert(r);
  EXPECT_EQ(parts, body_rows("t.txt"));
  // .vtu: the simplices whole (copies of the images they use), for ParaView: every
  // triangle positive, their areas the box's.
  const Outcome vtu = run("mesh " + in + " --periodic 0,0,4,4 -q -o " + path("t.vtu"));
  ASSERT_EQ(vtu.code, 0) << vtu.err;
  const std::string xml = slurp(path("t.vtu"));
  EXPECT_NE(xml.find("NumberOfCells=\"32\""), std::string::npos);
  EXPECT_NE(xml.find("Name=\"point_index\""), std::string::npos);
  auto numbers_after = [&](const std::string& marker) {
    std::size_t at = xml.find('>', xml.find(marker)) + 1;
    std::istringstream values(xml.substr(at, xml.find("</DataArray>", at) - at));
    return std::vector<double>((std::istream_iterator<double>(values)), std::istream_iterator<double>());
  };
  const std::vector<double> xyz = numbers_after("NumberOfComponents=\"3\"");
  const std::vector<double> conn = numbers_after("Name=\"connectivity\"");
  ASSERT_EQ(conn.size(), 96u);
  EXPECT_GT(xyz.size(), 48u);  // the 16 points and some image copies
  double area = 0;
  for (std::size_t t = 0; t < 32; ++t) {
    const double* a = &xyz[3 * static_cast<std::size_t>(conn[3 * t])];
    const double* b = &xyz[3 * static_cast<std::size_t>(conn[3 * t + 1])];
    const double* c = &xyz[3 * static_cast<std::size_t>(conn[3 * t + 2])];
    const double twice = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    EXPECT_GT(twice, 0) << "triangle " << t;
    area += twice / 2;
  }
  EXPECT_EQ(area, 16.0);

  // One seed on the torus: its six triangles (each with seed 5 at offset 0), its six
  // neighbour images, its unit-square cell with each facet's offset.
  const Outcome star = run("star " + in + " --seed 5 --periodic 0,0,4,4");
  ASSERT_EQ(star.code, 0) << star.err;
  EXPECT_EQ(std::count(star.out.begin(), star.out.end(), '\n'), 6) << star.out;
  const Outcome nb = run("neighbors " + in + " --seed 0 --periodic 0,0,4,4");
  ASSERT_EQ(nb.code, 0) << nb.err;
  EXPECT_EQ(std::count(nb.out.begin(), nb.out.end(), '\n'), 6) << nb.out;
  EXPECT_NE(nb.out.find("3 -1 0\n"), std::string::npos) << "point 3 = (3, 0), one box length left:\n" << nb.out;
  const Outcome cell = run("cell " + in + " --seed 0 --periodic 0,0,4,4 --json");
  ASSERT_EQ(cell.code, 0) << cell.err;
  EXPECT_NE(cell.out.find("\"volume\": 1.0"), std::string::npos) << cell.out;
  EXPECT_NE(cell.out.find("\"offset\""), std::string::npos) << cell.out;

  struct Bad {
    std::string args, needle;
  };
  const std::string outside = write("outside.txt", "0.5 0.5\n0.25 0.75\n1 0.5\n0.1 0.1\n");
  const std::vector<Bad> bad = {
      {"mesh " + outside + " --periodic 0,0,1,1 -o " + path("x.npz"), "point 2 lies outside the periodic box"},
      {"mesh " + in + " --periodic 0,0,4 -o " + path("x.npz"), "even count"},
      {"mesh " + in + " --periodic 0,4,4,4 -o " + path("x.npz"), "axis 1"},
      {"mesh " + in + " --periodic 0,0,0,4,4,4 -o " + path("x.npz"), "3-d box"},
      {"mesh " + in + " --periodic 0,0,4,4 -o " + path("x.msh"), ".vtu"},
      {"mesh " + in + " --periodic 0,0,4,4 --merge-duplicates -o " + path("x.npz"), "--merge-duplicates"},
      {"mesh " + in + " --periodic 0,0,4,4 --server 127.0.0.1:1 -o " + path("x.npz"), "go with `upload`"},
      {"mesh " + in + " --periodic 0,0,4,4 --seeds 3:99 -o " + path("x.npz"), "need 0 <= A <= B <= 16"},
      {"cell " + in + " --seed 0 --periodic 0,0,4,4 --box 0,0,1,1", "do not apply"},
      {"star " + in + " --seed 16 --periodic 0,0,4,4", "out of range"},
  };
  for (const Bad& b : bad) {
    const Outcome o = run(b.args);
    EXPECT_EQ(o.code, 2) << b.args << "\n" << o.err;
    EXPECT_NE(o.err.find(b.needle), std::string::npos) << b.args << "\n" << o.err;
    EXPECT_FALSE(fs::exists(path("x.npz")) || fs::exists(path("x.msh"))) << b.args;
  }
  for (const std::string& name : listing()) EXPECT_EQ(name.find(".partial"), std::string::npos) << name;
}

TEST_F(Cli, BadInputsExitTwoWithOneClearLineAndNoOutput) {
  struct Bad {
    std::string args, needle;
  };
  const std::string good = points(2, 50, 4);
  const std::vector<Bad> cases = {
      {"mesh " + path("missing.txt") + " -o OUT", "missing.txt: cannot open"},
      {"mesh " + write("empty.txt", "") + " -o OUT", "empty.txt: no points"},
      {"mesh " + write("nan.txt", "0 0\n1 0\nnan 1\n") + " -o OUT", "nan.txt:3: coordinate 0 is not finite"},
      {"mesh " + write("ragged.txt", "0 0\n1 0 3\n") + " -o OUT", "ragged.txt:2: has 3 coordinates"},
      {"mesh " + write("word.txt", "0 0\n1 zero\n") + " -o OUT", "word.txt:2: cannot parse 'zero'"},
      {"mesh " + write("few.txt", "0 0\n1 0\n") + " -o OUT", "2 points given"},
      {"mesh " + write("dup.txt", "0 0\n1 0\n0 1\n1 0\n") + " -o OUT",
       "points 1 and 3 are equal (use --merge-duplicates"},
      {"mesh " + write("flat.txt", "0 0 0\n1 0 0\n0 1 0\n1 1 0\n") + " -o OUT", "span only a 2-dimensional"},
      {"mesh " + write("huge.txt", "0 0\n1 0\n0 1e300\n") + " -o OUT", "huge.txt:3: coordinate 1 has magnitude"},
      {"mesh " + good + " -o " + "OUT.unknown", "unknown output format"},
      {"mesh " + good + " -o OUT --seeds 5", "--seeds: expected A:B"},
      {"mesh " + good + " -o OUT --seeds 10:99", "need 0 <= A <= B <= 50"},
      {"star " + good + " --seed 50", "seed 50 is out of range"},
      {"star " + good + " --seed -1", "seed -1 is out of range"},
      {"check " + good + " " + write("badmesh.txt", "0 1\n"), "badmesh.txt:1: has 2 indices, expected 3"},
  };
  for (Bad b : cases) {
    const auto at = b.args.find("OUT");
    if (at != std::string::npos) b.args.replace(at, 3, path("out"));
    const Outcome r = run(b.args);
    EXPECT_EQ(r.code, 2) << b.args << "\n" << r.err;
    EXPECT_NE(r.err.find(b.needle), std::string::npos) << b.args << "\nstderr: " << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << "one line: " << r.err;
    for (const std::string& name : listing()) {
      EXPECT_NE(name.rfind("out", 0), 0u) << "left behind: " << name;
    }
  }
  // An output that is the input is refused, whatever its spelling, and the input kept.
  const std::string before = slurp(good);
  for (const std::string& cmd :
       {"mesh " + good + " -o " + good, "graph " + good + " -o " + good, "cells " + good + " -o " + good,
        "mesh " + good + " -o " + path("./") + good.substr(good.rfind('/') + 1)}) {
    const Outcome r = run(cmd);
    EXPECT_EQ(r.code, 2) << cmd;
    EXPECT_NE(r.err.find("would overwrite the input"), std::string::npos) << cmd << "\n" << r.err;
    EXPECT_EQ(slurp(good), before) << cmd;
  }
  // --merge-duplicates accepts the duplicate and maps it to its first occurrence.
  const Outcome merged = run("mesh -q " + path("dup.txt") + " -o " + path("merged.simplices") + " --merge-duplicates");
  EXPECT_EQ(merged.code, 0) << merged.err;
  EXPECT_EQ(slurp(path("merged.simplices")), "0 1 2\n");
  // Per-seed commands print input indices too; a merged duplicate never appears.
  const std::string dup2 = write("dup2.txt", "0 0\n1 0\n0 1\n1 0\n1 1\n0.4 0.6\n");
  const Outcome star = run("star " + dup2 + " --seed 5 --merge-duplicates");
  EXPECT_EQ(star.code, 0) << star.err;
  // Positively oriented (counter-clockwise): 0 2 5 and 2 4 5 are clockwise, so swapped.
  EXPECT_EQ(star.out, "0 1 5\n0 5 2\n1 4 5\n2 5 4\n");
}

}  // namespace

namespace {

TEST_F(Cli, GraphExactIsTheMeshEdgesAndApproximateWorksInAnyDimension) {
  const std::string pts = points(3, 400, 71);
  ASSERT_EQ(run("mesh " + pts + " -o " + path("m.simplices") + " -q").code, 0);
  ASSERT_EQ(run("graph " + pts + " -o " + path("g.edges") + " -q").code, 0);
  std::set<std::pair<int, int>> mesh_edges;
  {
    std::istringstream in(slurp(path("m.simplices")));
    int a, b, c, d;
    while (in >> a >> b >> c >> d) {
      const int v[4] = {a, b, c, d};
      for (int i = 0; i < 4; ++i) {
        for (int j = i + 1; j < 4; ++j) mesh_edges.emplace(std::minmax(v[i], v[j]));
      }
    }
  }
  std::string expected;
  for (auto [a, b] : mesh_edges) expected += std::to_string(a) + " " + std::to_string(b) + "\n";
  EXPECT_EQ(slurp(path("g.edges")), expected);
  // Approximate: a subset, identical for 1 and 2 threads, as text and .npy.
  ASSERT_EQ(run("graph " + pts + " -o " + path("a1.edges") + " --approx --misses 50 --threads 1 -q").code, 0);
  ASSERT_EQ(run("graph " + pts + " -o " + path("a2.edges") + " --approx --misses 50 --threads 2 -q").code, 0);
  EXPECT_EQ(slurp(path("a1.edges")), slurp(path("a2.edges")));
  std::istringstream in(slurp(path("a1.edges")));
  int a, b, count = 0;
  while (in >> a >> b) {
    EXPECT_TRUE(mesh_edges.count({a, b})) << a << " " << b;
    ++count;
  }
  EXPECT_GT(count, static_cast<int>(mesh_edges.size()) * 9 / 10);
  const Outcome npy = run("graph " + pts + " -o " + path("a.npy") + " --approx --misses 50");
  EXPECT_EQ(npy.code, 0);
  EXPECT_NE(npy.err.find("certified (approximate) edges"), std::string::npos) << npy.err;
}

// The vectorized filters run four lanes where the CPU has AVX2 and two otherwise;
// forcing two must change nothing in the output (exact mesh in 5-d, where wraps scan
// hundreds of candidates, and an 8-d approximate graph).
TEST_F(Cli, SameOutputWithTwoLaneSimd) {
  const std::string pts5 = points(5, 300, 73), pts8 = points(8, 150, 74);
  for (const std::string simd : {"", "SPOKEMESH_SIMD=sse2"}) {
    const std::string tag = simd.empty() ? "default" : "sse2";
    SCOPED_TRACE(tag);
    const Outcome mesh = run("mesh " + pts5 + " -o " + path(tag + ".simplices") + " -q", simd);
    ASSERT_EQ(mesh.code, 0) << mesh.err;
    const Outcome graph = run("graph " + pts8 + " -o " + path(tag + ".edges") + " --approx --misses 30 -q", simd);
    ASSERT_EQ(graph.code, 0) << graph.err;
  }
  EXPECT_EQ(slurp(path("default.simplices")), slurp(path("sse2.simplices")));
  EXPECT_EQ(slurp(path("default.edges")), slurp(path("sse2.edges")));
  EXPECT_FALSE(slurp(path("sse2.edges")).empty());
}

TEST_F(Cli, HighDimensionsNeedApproxAndSaySo) {
  const std::string pts = points(10, 120, 72);
  const Outcome exact = run("graph " + pts + " -o " + path("g.edges"));
  EXPECT_EQ(exact.code, 2);
  EXPECT_NE(exact.err.find("--approx"), std::string::npos) << exact.err;
  EXPECT_EQ(std::count(exact.err.begin(), exact.err.end(), '\n'), 1);
  EXPECT_FALSE(fs::exists(path("g.edges")));
  const Outcome star = run("star " + pts + " --seed 0");
  EXPECT_EQ(star.code, 2);
  EXPECT_NE(star.err.find("--approx"), std::string::npos) << star.err;
  const Outcome approx = run("neighbors " + pts + " --seed 0 --approx --misses 30");
  EXPECT_EQ(approx.code, 0) << approx.err;
  EXPECT_FALSE(approx.out.empty());
  EXPECT_NE(approx.err.find("certified neighbours"), std::string::npos);
  EXPECT_EQ(run("neighbors " + pts + " --seed 0 --approx --mode spokes --misses 30").code, 0);
  EXPECT_EQ(run("neighbors " + pts + " --seed 0 --approx --mode nope").code, 2);
}

}  // namespace

namespace {

// Reads a text file of one number a line.
std::vector<double> numbers(const std::string& text) {
  std::vector<double> out;
  std::istringstream s(text);
  for (std::string word; s >> word;) out.push_back(word == "nan" ? std::nan("") : std::stod(word));
  return out;
}

}  // namespace

TEST_F(Cli, InterpolateReproducesLinearFunctionsAndGrids) {
  // Values of 1 + 2x - 3y at 2,000 points; every method at query points inside the hull,
  // and a raster whose corners lie outside it (the fill value).
  const auto c = spokemesh::testing::uniform_points(2, 2000, 53);
  std::ostringstream values, queries;
  values.precision(17);
  queries.precision(17);
  for (std::size_t i = 0; i < 2000; ++i) values << 1 + 2 * c[2 * i] - 3 * c[2 * i + 1] << "\n";
  std::vector<std::pair<double, double>> q;
  for (int i = 0; i < 50; ++i) q.emplace_back(0.2 + 0.6 * i / 49.0, 0.3 + 0.4 * ((i * 7) % 50) / 49.0);
  for (const auto& [x, y] : q) queries << x << " " << y << "\n";
  const std::string pts = points(2, 2000, 53);
  const std::string vals = write("values.txt", values.str()), qs = write("queries.txt", queries.str());
  for (const char* method : {"natural", "linear"}) {
    const Outcome r = run("interpolate " + pts + " " + vals + " " + qs + " -o " + path(std::string(method) + ".txt") +
                          " --method " + method + " --threads 2");
    ASSERT_EQ(r.code, 0) << r.err;
    const std::vector<double> got = numbers(slurp(path(std::string(method) + ".txt")));
    ASSERT_EQ(got.size(), q.size()) << method;
    for (std::size_t i = 0; i < q.size(); ++i) {
      EXPECT_NEAR(got[i], 1 + 2 * q[i].first - 3 * q[i].second, 1e-12) << method << " query " << i;
    }
  }
  const Outcome nearest =
      run("interpolate " + pts + " " + vals + " " + qs + " -o " + path("nearest.txt") + " --method nearest -q");
  ASSERT_EQ(nearest.code, 0) << nearest.err;
  EXPECT_EQ(nearest.err, "");
  EXPECT_EQ(numbers(slurp(path("nearest.txt"))).size(), q.size());
  // A 7 x 5 raster over [-0.5, 1.5]^2 as .npy: shape (5, 7), corners outside (NaN).
  const Outcome grid =
      run("interpolate " + pts + " " + vals + " --grid -0.5,-0.5,1.5,1.5,7,5 -o " + path("grid.npy") + " -q");
  ASSERT_EQ(grid.code, 0) << grid.err;
  const std::string npy = slurp(path("grid.npy"));
  EXPECT_NE(npy.find("'shape': (5, 7)"), std::string::npos);
  const std::size_t header = npy.size() - 35 * sizeof(double);
  double corner, centre;
  std::memcpy(&corner, npy.data() + header, sizeof corner);
  std::memcpy(&centre, npy.data() + header + (2 * 7 + 3) * sizeof(double),
              sizeof centre);  // row 2, column 3: (0.5, 0.5)
  EXPECT_TRUE(std::isnan(corner));
  EXPECT_NEAR(centre, 1 + 2 * 0.5 - 3 * 0.5, 1e-12);
  // Bad input: named, exit 2, nothing written.
  const std::string short_values = write("short.txt", "1\n2\n3\n");
  const Outcome bad = run("interpolate " + pts + " " + short_values + " " + qs + " -o " + path("bad.txt"));
  EXPECT_EQ(bad.code, 2);
  EXPECT_NE(bad.err.find("3 values for 2000 points"), std::string::npos) << bad.err;
  const Outcome both = run("interpolate " + pts + " " + vals + " " + qs + " --grid 0,0,1,1,2,2 -o " + path("b.txt"));
  EXPECT_EQ(both.code, 2);
  EXPECT_NE(both.err.find("not both"), std::string::npos) << both.err;
  const Outcome high = run("interpolate " + points(4, 100, 3) + " " + vals + " " + qs + " -o " + path("h.txt"));
  EXPECT_EQ(high.code, 2);
  EXPECT_NE(high.err.find("--method natural (2-d and 3-d)"), std::string::npos) << high.err;
  for (const std::string& name : listing()) EXPECT_EQ(name.find(".partial"), std::string::npos) << name;
  EXPECT_FALSE(fs::exists(path("bad.txt")));
}
