// Point and mesh files: every malformed input is refused with one message naming
// the file and the line or index; writers are atomic.
#include <cstring>
#include <filesystem>
#include <fstream>

#include "spokemesh/io.hpp"
#include "support.hpp"

namespace spokemesh {
namespace {

std::string temp_path(const std::string& name) { return ::testing::TempDir() + "/" + name; }

void write_file(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary) << bytes;
}

std::string npy(const std::string& descr, const std::string& shape, const std::string& data, bool fortran = false) {
  std::string dict = "{'descr': '" + descr + "', 'fortran_order': " + (fortran ? "True" : "False") + ", 'shape': " + shape + ", }";
  while ((10 + dict.size() + 1) % 64 != 0) dict.push_back(' ');
  dict.push_back('\n');
  std::string out("\x93NUMPY\x01\x00", 8);
  out.push_back(static_cast<char>(dict.size() & 0xFF));
  out.push_back(static_cast<char>(dict.size() >> 8));
  return out + dict + data;
}

std::string doubles(std::initializer_list<double> values) {
  std::string s(values.size() * 8, '\0');
  std::size_t k = 0;
  for (double v : values) std::memcpy(&s[8 * k++], &v, 8);
  return s;
}

TEST(TextPoints, ParsesCommentsCommasAndBlankLines) {
  auto ps = parse_text_points("# header\n0 0\n\n1, 0  # trailing\n0,1\n+2.5e0 -1\n", "pts.txt");
  ASSERT_TRUE(ps.is_ok()) << ps.status().message();
  EXPECT_EQ(ps->dimension(), 2);
  EXPECT_EQ(ps->size(), 4u);
  EXPECT_EQ(ps->point(3)[0], 2.5);
}

TEST(TextPoints, RefusesBadInputNamingFileAndLine) {
  struct Bad {
    std::string text, needle;
  };
  for (const Bad& b : std::vector<Bad>{
           {"", "pts.txt: no points"},
           {"# only a comment\n\n", "pts.txt: no points"},
           {"0 0\n1 x\n", "pts.txt:2: cannot parse 'x'"},
           {"0 0\n1 \x01\x02zz\n", "pts.txt:2: cannot parse '??zz'"},
           {"0 0\n1 0 0\n", "pts.txt:2: has 3 coordinates, but earlier lines have 2"},
           {"0 0\nnan 1\n", "pts.txt:2: coordinate 0 is not finite"},
           {"0 0\n1 inf\n", "pts.txt:2: coordinate 1 is not finite"},
           {"0 0\n1 1e200\n", "pts.txt:2: coordinate 1 has magnitude above 1e100"},
       }) {
    auto ps = parse_text_points(b.text, "pts.txt");
    ASSERT_FALSE(ps.is_ok()) << b.text;
    EXPECT_EQ(ps.status().code(), Code::kInvalidArgument);
    EXPECT_NE(ps.status().message().find(b.needle), std::string::npos) << ps.status().message();
  }
}

TEST(PointSetValidate, RefusesGeometricProblems) {
  struct Bad {
    int d;
    std::vector<double> c;
    std::string needle;
  };
  for (const Bad& b : std::vector<Bad>{
           {2, {0, 0, 1, 0}, "2 points given; a 2-d mesh needs at least 3"},
           {2, {0, 0, 1, 0, 0, 1, 1, 0}, "points 1 and 3 are equal"},
           {2, {0, 0, 1, 1, 2, 2, 3, 3}, "span only a 1-dimensional affine subspace"},
           {3, {0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0, 2, 3, 0}, "span only a 2-dimensional"},
           {1, {0, 1, 2}, "dimension 1 is not supported"},
           {9, std::vector<double>(90, 0.0), "dimension 9 is not supported"},
       }) {
    PointSet ps(b.d, b.c);
    const Status s = ps.validate("pts.txt");
    ASSERT_FALSE(s.is_ok()) << b.needle;
    EXPECT_NE(s.message().find(b.needle), std::string::npos) << s.message();
    EXPECT_EQ(s.message().rfind("pts.txt", 0), 0u) << s.message();
  }
}

TEST(PointSetValidate, MergeDuplicatesMapsToFirstOccurrence) {
  PointSet ps(2, {0, 0, 1, 0, 0, 0, 0, 1, 1, 0});
  const auto map = ps.merge_duplicates();
  EXPECT_EQ(map, (std::vector<std::uint32_t>{0, 1, 0, 2, 1}));
  EXPECT_EQ(ps.size(), 3u);
  EXPECT_TRUE(ps.validate("x").is_ok());
}

TEST(NpyPoints, ReadsFloat64AndFloat32) {
  const std::string p64 = temp_path("p64.npy");
  write_file(p64, npy("<f8", "(3, 2)", doubles({0, 0, 1, 0, 0, 1})));
  auto a = read_points(p64);
  ASSERT_TRUE(a.is_ok()) << a.status().message();
  EXPECT_EQ(a->size(), 3u);
  EXPECT_EQ(a->point(2)[1], 1.0);
  std::string f32(6 * 4, '\0');
  const float fv[6] = {0, 0, 1, 0, 0, 0.5f};
  std::memcpy(f32.data(), fv, sizeof fv);
  const std::string p32 = temp_path("p32.npy");
  write_file(p32, npy("<f4", "(3, 2)", f32));
  auto b = read_points(p32);
  ASSERT_TRUE(b.is_ok()) << b.status().message();
  EXPECT_EQ(b->point(2)[1], 0.5);
}

TEST(NpyPoints, RefusesBadArrays) {
  struct Bad {
    std::string bytes, needle;
  };
  for (const Bad& b : std::vector<Bad>{
           {"not numpy at all", "bad magic"},
           {npy("<i8", "(3, 2)", std::string(48, '\0')), "dtype '<i8' is not supported"},
           {npy("<f8", "(3, 2)", doubles({0, 0, 1, 0, 0, 1}), true), "Fortran order"},
           {npy("<f8", "(6,)", doubles({0, 0, 1, 0, 0, 1})), "shape (n, d)"},
           {npy("<f8", "(3, 2)", doubles({0, 0, 1, 0, 0})), "truncated .npy data"},
           {npy("<f8", "(3, 2)", doubles({0, 0, 1, NAN, 0, 1})), "element [1, 1] is not finite"},
           {npy("<f8", "(0, 2)", ""), "no points"},
           {[] {  // a corrupted key: the message names the problem, not the raw header
              std::string bytes = npy("<f8", "(3, 2)", doubles({0, 0, 1, 0, 0, 1}));
              bytes[bytes.find("shape")] = '\x87';
              return bytes;
            }(),
            "malformed .npy header (no 'shape' entry)"},
       }) {
    const std::string path = temp_path("bad.npy");
    write_file(path, b.bytes);
    auto ps = read_points(path);
    ASSERT_FALSE(ps.is_ok()) << b.needle;
    EXPECT_NE(ps.status().message().find(b.needle), std::string::npos) << ps.status().message();
    EXPECT_NE(ps.status().message().find("bad.npy"), std::string::npos);
    EXPECT_EQ(ps.status().message().find('\n'), std::string::npos) << "one line";
  }
}

TEST(MeshWriter, WritesAtomicallyAndCleansUpWhenAbandoned) {
  PointSet ps(2, {0, 0, 1, 0, 0, 1, 1, 1});
  ASSERT_TRUE(ps.validate("x").is_ok());
  const std::string dir = temp_path("writer");
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  const std::string path = dir + "/mesh.simplices";
  std::filesystem::remove(path);
  {
    auto w = MeshWriter::open(path, ps);
    ASSERT_TRUE(w.is_ok());
    ASSERT_TRUE(w.value()->write(std::vector<std::uint32_t>{0, 1, 2}).is_ok());
    EXPECT_FALSE(std::filesystem::exists(path)) << "nothing appears before commit";
  }  // abandoned
  EXPECT_FALSE(std::filesystem::exists(path));
  EXPECT_TRUE(std::filesystem::is_empty(dir)) << "the temporary file is removed";
  for (const std::string ext : {".simplices", ".npy", ".vtu", ".msh", ".svg"}) {
    const std::string out = dir + "/mesh" + ext;
    auto w = MeshWriter::open(out, ps);
    ASSERT_TRUE(w.is_ok()) << ext;
    ASSERT_TRUE(w.value()->write(std::vector<std::uint32_t>{0, 1, 2, 1, 2, 3}).is_ok());
    ASSERT_TRUE(w.value()->commit().is_ok());
    EXPECT_GT(std::filesystem::file_size(out), 0u) << ext;
  }
  auto back = read_simplices(dir + "/mesh.npy", 3);
  ASSERT_TRUE(back.is_ok()) << back.status().message();
  EXPECT_EQ(back.value(), (std::vector<std::uint32_t>{0, 1, 2, 1, 2, 3}));
  auto text = read_simplices(dir + "/mesh.simplices", 3);
  ASSERT_TRUE(text.is_ok());
  EXPECT_EQ(text.value(), back.value());
}

TEST(MeshWriter, RefusesFormatsThatDoNotFitTheDimension) {
  EXPECT_NE(MeshWriter::format_for("m.vtu", 4).status().message().find("2-d and 3-d"), std::string::npos);
  EXPECT_NE(MeshWriter::format_for("m.svg", 3).status().message().find("2-d"), std::string::npos);
  EXPECT_NE(MeshWriter::format_for("m.obj", 2).status().message().find("unknown output format"), std::string::npos);
}

}  // namespace
}  // namespace spokemesh
