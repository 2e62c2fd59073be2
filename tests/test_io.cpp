// Point and mesh files: every malformed input is refused with one message naming
// the file and the line or index; writers are atomic.
#include <cstring>
#include <filesystem>
#include <fstream>

#include "spokemesh/io.hpp"
#include "spokemesh/periodic_box.hpp"
#include "support.hpp"

namespace spokemesh {
namespace {

std::string temp_path(const std::string& name) { return ::testing::TempDir() + "/" + name; }

void write_file(const std::string& path, const std::string& bytes) { std::ofstream(path, std::ios::binary) << bytes; }

std::string npy(const std::string& descr, const std::string& shape, const std::string& data, bool fortran = false) {
  std::string dict =
      "{'descr': '" + descr + "', 'fortran_order': " + (fortran ? "True" : "False") + ", 'shape': " + shape + ", }";
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

// README "Input": semicolons separate too, and a first line with no number is a header.
TEST(TextPoints, SemicolonsAndAHeaderLine) {
  auto ps = parse_text_points("# from a spreadsheet\n\nx;y\n0;0\n1 ; 0\n0;1\n", "pts.csv");
  ASSERT_TRUE(ps.is_ok()) << ps.status().message();
  EXPECT_EQ(ps->size(), 3u);
  EXPECT_EQ(ps->point(1)[0], 1.0);
  struct Bad {
    std::string text, needle;
  };
  for (const Bad& b : std::vector<Bad>{
           {"0 0\nx y\n1 0\n", "pts.csv:2: cannot parse 'x'"},  // only a first line is a header
           {"x,1\n0 0\n", "pts.csv:1: cannot parse 'x'"},       // a field is a number: no header
           {"x y\n", "pts.csv: no points"},
           {"+-1 0\n", "pts.csv:1: cannot parse '+-1'"},
           {"0x1 0\n", "pts.csv:1: cannot parse '0x1'"},
       }) {
    auto bad = parse_text_points(b.text, "pts.csv");
    ASSERT_FALSE(bad.is_ok()) << b.text;
    EXPECT_NE(bad.status().message().find(b.needle), std::string::npos) << bad.status().message();
  }
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

TEST(NpyPoints, ReadsIntegersExactly) {
  const std::int64_t edge = std::int64_t{1} << 53;
  const std::int64_t i64[6] = {0, -edge, 1, 0, edge, 7};
  std::string b64(sizeof i64, '\0');
  std::memcpy(b64.data(), i64, sizeof i64);
  const std::string p64 = temp_path("i64.npy");
  write_file(p64, npy("<i8", "(3, 2)", b64));
  auto a = read_points(p64);
  ASSERT_TRUE(a.is_ok()) << a.status().message();
  EXPECT_EQ(a->point(0)[1], -9007199254740992.0);
  EXPECT_EQ(a->point(2)[0], 9007199254740992.0);
  const std::int32_t i32[6] = {0, 0, 3, 0, 0, -4};
  std::string b32(sizeof i32, '\0');
  std::memcpy(b32.data(), i32, sizeof i32);
  const std::string p32 = temp_path("i32.npy");
  write_file(p32, npy("<i4", "(3, 2)", b32));
  auto b = read_points(p32);
  ASSERT_TRUE(b.is_ok()) << b.status().message();
  EXPECT_EQ(b->point(2)[1], -4.0);
  const std::int16_t i16[6] = {0, 0, 3, 0, 0, 5};
  std::string b16(sizeof i16, '\0');
  std::memcpy(b16.data(), i16, sizeof i16);
  const std::string p16 = temp_path("i16.npy");
  write_file(p16, npy("<i2", "(3, 2)", b16));
  auto c = read_points(p16);
  ASSERT_TRUE(c.is_ok()) << c.status().message();
  EXPECT_EQ(c->point(2)[1], 5.0);
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
           {npy(">f8", "(3, 2)", std::string(48, '\0')), "dtype '>f8' is not supported"},
           {npy("|u1", "(3, 2)", std::string(6, '\0')), "dtype '|u1' is not supported"},
           {[] {  // an int64 a double would round
              std::string b(48, '\0');
              const std::int64_t big = (std::int64_t{1} << 53) + 1;
              std::memcpy(&b[40], &big, 8);
              return npy("<i8", "(3, 2)", b);
            }(),
            "element [2, 1] = 9007199254740993 is not exactly a double"},
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

// Weights: one a point, text or .npy; radii become squared weights; every
// bad value or count is named by file and line or index.
TEST(Weights, ReadsTextAndNpyAndRadii) {
  auto w = parse_text_weights("# power weights\n0.25\n\n-1  # may be negative\n2e-3\n", "w.txt", 3,
                              WeightKind::kPowerWeight);
  ASSERT_TRUE(w.is_ok()) << w.status().message();
  EXPECT_EQ(w.value(), (std::vector<double>{0.25, -1, 2e-3}));
  auto r = parse_text_weights("0.5\n3\n0\n", "r.txt", 3, WeightKind::kRadius);
  ASSERT_TRUE(r.is_ok()) << r.status().message();
  EXPECT_EQ(r.value(), (std::vector<double>{0.25, 9, 0}));
  for (const std::string& shape : {std::string("(3,)"), std::string("(3, 1)")}) {
    const std::string path = temp_path("weights.npy");
    write_file(path, npy("<f8", shape, doubles({1.5, 0, -2})));
    auto n = read_weights(path, 3, WeightKind::kPowerWeight);
    ASSERT_TRUE(n.is_ok()) << shape << ": " << n.status().message();
    EXPECT_EQ(n.value(), (std::vector<double>{1.5, 0, -2}));
  }
  std::string f32(8, '\0');
  const float halves[2] = {0.5f, 4.0f};
  std::memcpy(f32.data(), halves, 8);
  auto f = parse_npy_weights(npy("<f4", "(2,)", f32), "r.npy", 2, WeightKind::kRadius);
  ASSERT_TRUE(f.is_ok()) << f.status().message();
  EXPECT_EQ(f.value(), (std::vector<double>{0.25, 16}));
}

TEST(Weights, RefusesBadValuesAndCountsNamingWhere) {
  struct Bad {
    std::string text;
    WeightKind kind;
    std::string needle;
  };
  for (const Bad& b : std::vector<Bad>{
           {"1\n2\n", WeightKind::kPowerWeight, "w.txt: 2 weights for 3 points"},
           {"1\n2\n3\n4\n", WeightKind::kRadius, "w.txt: 4 radii for 3 points"},
           {"1\nx\n3\n", WeightKind::kPowerWeight, "w.txt:2: cannot parse 'x'"},
           {"1\n2 3\n4\n", WeightKind::kPowerWeight, "w.txt:2: has 2 numbers; expected one weight a line"},
           {"1\nnan\n3\n", WeightKind::kPowerWeight, "w.txt:2: weight is not finite"},
           {"1\n2\n-inf\n", WeightKind::kPowerWeight, "w.txt:3: weight is not finite"},
           {"1\n2\n1e250\n", WeightKind::kPowerWeight, "w.txt:3: weight has magnitude above 1e200"},
           {"1\n-0.5\n3\n", WeightKind::kRadius, "w.txt:2: radius -0.500000 is negative"},
       }) {
    auto w = parse_text_weights(b.text, "w.txt", 3, b.kind);
    ASSERT_FALSE(w.is_ok()) << b.text;
    EXPECT_EQ(w.status().code(), Code::kInvalidArgument);
    EXPECT_NE(w.status().message().find(b.needle), std::string::npos) << w.status().message();
  }
  struct BadNpy {
    std::string bytes, needle;
  };
  for (const BadNpy& b : std::vector<BadNpy>{
           {npy("<f8", "(3, 2)", doubles({0, 0, 1, 0, 0, 1})), "must have shape (n,) or (n, 1)"},
           {npy("<i8", "(3,)", std::string(24, '\0')), "dtype '<i8' is not supported"},
           {npy("<f8", "(2,)", doubles({0, 1})), "w.npy: 2 weights for 3 points"},
           {npy("<f8", "(3,)", doubles({0, 1})), "truncated .npy data"},
           {npy("<f8", "(2305843009213693952,)", doubles({0, 1})), "truncated .npy data"},
           {npy("<f8", "(3,)", doubles({0, NAN, 1})), "w.npy: index 1: weight is not finite"},
       }) {
    auto w = parse_npy_weights(b.bytes, "w.npy", 3, WeightKind::kPowerWeight);
    ASSERT_FALSE(w.is_ok()) << b.needle;
    EXPECT_NE(w.status().message().find(b.needle), std::string::npos) << w.status().message();
  }
  const Status missing = read_weights(temp_path("no-such-weights.txt"), 3, WeightKind::kPowerWeight).status();
  EXPECT_NE(missing.message().find("no-such-weights.txt: cannot open for reading"), std::string::npos)
      << missing.message();
}

// The periodic box: parsed as --box is, LO < HI on every axis, and every
// point in [LO, HI), the first one outside named with its axis and side.
TEST(PeriodicBoxTest, ParsesAndChecksPointsNamingTheFirstOutside) {
  auto box = PeriodicBox::parse("0,-1,2,1", "--periodic");
  ASSERT_TRUE(box.is_ok()) << box.status().message();
  EXPECT_EQ(box->dimension(), 2);
  EXPECT_EQ(box->lo(), (std::vector<double>{0, -1}));
  EXPECT_EQ(box->hi(), (std::vector<double>{2, 1}));
  const PointSet inside(2, {0, -1, 1.5, 0.999, 0.25, 0});
  EXPECT_TRUE(box->check_contains(inside, "pts.txt").is_ok());
  struct Bad {
    std::vector<double> coords;
    std::string needle;
  };
  for (const Bad& b : std::vector<Bad>{
           {{0, 0, 2, 0.5}, "pts.txt: point 1 lies outside the periodic box: coordinate 0 is 2, not below HI 2"},
           {{0, 0, 1, -1.5}, "pts.txt: point 1 lies outside the periodic box: coordinate 1 is -1.5, below LO -1"},
       }) {
    const Status s = box->check_contains(PointSet(2, b.coords), "pts.txt");
    EXPECT_EQ(s.code(), Code::kInvalidArgument);
    EXPECT_NE(s.message().find(b.needle), std::string::npos) << s.message();
  }
  EXPECT_NE(box->check_contains(PointSet(3, {0, 0, 0}), "pts.txt").message().find("3-d and the periodic box 2-d"),
            std::string::npos);
  for (const auto& [text, needle] : std::vector<std::pair<std::string, std::string>>{
           {"0,0,1", "an even count"},
           {"0,0,1,0", "--periodic: axis 1: LO 0 is not below HI 0"},
           {"2,0,1,1", "--periodic: axis 0: LO 2 is not below HI 1"},
           {"0,x,1,1", "value 1 ('x') is not a finite number"},
           {"0,1", "a 1-d box"},
           {"0,0,1,1e300", "axis 1: the sides must be finite, at most 1e100"},
       }) {
    auto bad = PeriodicBox::parse(text, "--periodic");
    ASSERT_FALSE(bad.is_ok()) << text;
    EXPECT_NE(bad.status().message().find(needle), std::string::npos) << bad.status().message();
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
