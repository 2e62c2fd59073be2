// Pieces (pieces.hpp): a set kept as the nodes of its split, each with its halo. Every
// seed's star, neighbours and cell computed from its piece alone, mapped back, equal
// the whole set's bytes (clipped cells whenever their reach is held, which the server
// checks before answering); the layout is a function of the set; files are checked.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "spokemesh/cells.hpp"
#include "spokemesh/certify.hpp"
#include "spokemesh/domain.hpp"
#include "spokemesh/kd_tree.hpp"
#include "spokemesh/pieces.hpp"
#include "spokemesh/star.hpp"
#include "spokemesh/voronoi.hpp"
#include "support.hpp"

namespace spokemesh {
namespace {

namespace fs = std::filesystem;
using testing::grid_points;
using testing::make_points;
using testing::uniform_points;

std::string read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

std::vector<double> clustered(int d, std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> where(0, 1);
  std::normal_distribution<double> spread(0, 0.02);
  std::vector<double> centres(5 * static_cast<std::size_t>(d)), c;
  for (double& v : centres) v = where(rng);
  for (std::size_t i = 0; i < n; ++i) {
    for (int j = 0; j < d; ++j) c.push_back(centres[(i % 5) * static_cast<std::size_t>(d) + j] + spread(rng));
  }
  return c;
}

class TempDir {
 public:
  TempDir() {
    path_ = fs::temp_directory_path() /
            ("spokemesh-pieces-" + std::to_string(::getpid()) + "-" + std::to_string(counter_++));
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  std::string str() const { return path_.string(); }

 private:
  fs::path path_;
  static inline int counter_ = 0;
};

bool same_cell(const VoronoiCell& a, const VoronoiCell& b) {
  if (a.seed != b.seed || a.vertices != b.vertices || a.vertex_simplices != b.vertex_simplices ||
      a.facets.size() != b.facets.size() || a.volume != b.volume || a.centroid != b.centroid || a.bounded != b.bounded)
    return false;
  for (std::size_t k = 0; k < a.facets.size(); ++k) {
    const VoronoiFacet &f = a.facets[k], &g = b.facets[k];
    if (f.neighbor != g.neighbor || f.vertices != g.vertices || f.area != g.area || f.normal != g.normal) return false;
  }
  return true;
}

struct Case {
  const char* name;
  int d;
  std::vector<double> coords;
  std::uint32_t piece_points;
};

// Every seed from its piece equals the whole set's answer, bytes for bytes.
void check_every_seed(const Case& c) {
  SCOPED_TRACE(c.name);
  const PointSet whole = make_points(c.d, c.coords);
  const KdTree whole_tree(whole);
  TempDir dir;
  PieceOptions options;
  options.piece_points = c.piece_points;
  options.threads = 2;
  auto manifest = store_pieces(whole, "set", dir.str(), options);
  ASSERT_TRUE(manifest.is_ok()) << manifest.status().message();
  const PieceManifest& m = manifest.value();
  ASSERT_GE(m.pieces.size(), 3u);

  // The manifest reads back as written; the owner map agrees with the pieces.
  const std::string text = read_file(pieces_dir(dir.str(), "set") + "/manifest");
  ASSERT_EQ(text, manifest_text(m));
  auto parsed = parse_manifest(text, "manifest");
  ASSERT_TRUE(parsed.is_ok()) << parsed.status().message();
  EXPECT_EQ(manifest_text(parsed.value()), text);
  const std::string owners_bytes = read_file(pieces_dir(dir.str(), "set") + "/owners");
  ASSERT_EQ(owners_bytes.size(), whole.size() * 4);
  std::vector<std::uint32_t> owners(whole.size());
  std::memcpy(owners.data(), owners_bytes.data(), owners_bytes.size());

  const Domain box = Domain::bounding_box(whole);
  std::uint64_t cells_held = 0, cells_completed = 0;
  std::vector<std::uint64_t> seen(m.pieces.size(), 0);
  for (std::uint32_t p = 0; p < m.pieces.size(); ++p) {
    auto piece = read_piece(pieces_dir(dir.str(), "set") + "/" + std::to_string(p) + ".piece", m, p);
    ASSERT_TRUE(piece.is_ok()) << piece.status().message();
    auto local = piece_point_set(piece.value());
    ASSERT_TRUE(local.is_ok()) << local.status().message();
    const KdTree tree(local.value());
    StarWalker walker(tree), whole_walker(whole_tree);
    ClippedCellBuilder builder(tree, box), whole_builder(whole_tree, box);
    const StarCertifier certifier(local.value(), m.global_box);
    const std::vector<double> unheld = m.global_box;
    for (std::uint32_t k = 0; k < piece->ids.size(); ++k) {
      if (!piece->own[k]) continue;
      const auto id = static_cast<std::uint32_t>(piece->ids[k]);
      ASSERT_EQ(owners[id], p) << "seed " << id;
      ++seen[p];
      Star star, expected;
      ASSERT_TRUE(walker.compute(k, star).is_ok());
      ASSERT_TRUE(whole_walker.compute(id, expected).is_ok());
      VoronoiCell cell = voronoi_cell(local.value(), star);
      const VoronoiCell expected_cell = voronoi_cell(whole, expected);
      to_global(star, piece->ids);
      ASSERT_EQ(star.simplices, expected.simplices) << "seed " << id;
      ASSERT_EQ(star.hull_facets, expected.hull_facets) << "seed " << id;
      to_global(cell, piece->ids);
      ASSERT_TRUE(same_cell(cell, expected_cell)) << "unclipped cell of seed " << id;

      auto clipped = builder.cell(k);
      ASSERT_TRUE(clipped.is_ok());
      // What the server checks before answering from the piece alone.
      const double reach2 = builder.last_reach2();
      if (reach2 > 0 && !certifier.ball_is_held(k, reach2 * (1 + 4 * kDistanceMargin), piece->held_box, {}, unheld)) {
        ++cells_completed;
        continue;
      }
      ++cells_held;
      auto expected_clipped = whole_builder.cell(id);
      ASSERT_TRUE(expected_clipped.is_ok());
      to_global(clipped.value(), piece->ids);
      ASSERT_TRUE(same_cell(clipped.value(), expected_clipped.value())) << "clipped cell of seed " << id;
    }
  }
  for (std::uint32_t p = 0; p < m.pieces.size(); ++p) EXPECT_EQ(seen[p], m.pieces[p].count);
  std::printf("%s: %zu pieces, clipped cells held %llu, completed from the store %llu\n", c.name, m.pieces.size(),
              static_cast<unsigned long long>(cells_held), static_cast<unsigned long long>(cells_completed));
  EXPECT_GT(cells_held, 2 * cells_completed);

  // The same layout, bytes for bytes, from another run (one thread).
  TempDir again;
  options.threads = 1;
  auto second = store_pieces(whole, "set", again.str(), options);
  ASSERT_TRUE(second.is_ok());
  for (const auto& entry : fs::directory_iterator(pieces_dir(dir.str(), "set"))) {
    const std::string name = entry.path().filename().string();
    EXPECT_EQ(read_file(entry.path().string()), read_file(pieces_dir(again.str(), "set") + "/" + name)) << name;
  }
}

TEST(Pieces, EverySeedFromItsPieceIsTheWholeSetsAnswer3d) {
  check_every_seed({"uniform 3-d", 3, uniform_points(3, 3000, 7), 400});
  check_every_seed({"clustered 3-d", 3, clustered(3, 2500, 8), 300});
  check_every_seed({"grid 3-d", 3, grid_points(3, 11), 250});
}

TEST(Pieces, EverySeedFromItsPieceIsTheWholeSetsAnswer2d) {
  check_every_seed({"uniform 2-d", 2, uniform_points(2, 3000, 9), 300});
  check_every_seed({"grid 2-d", 2, grid_points(2, 40), 200});
}

TEST(Pieces, ShardsAreContiguousRunsCoveringEveryPiece) {
  for (std::uint32_t pieces : {1u, 2u, 5u, 16u, 17u}) {
    for (std::uint32_t shards : {1u, 2u, 3u, 4u}) {
      std::uint32_t last = 0;
      std::vector<int> count(shards, 0);
      for (std::uint32_t p = 0; p < pieces; ++p) {
        const std::uint32_t s = shard_of_piece(p, pieces, shards);
        ASSERT_LT(s, shards);
        ASSERT_GE(s, last) << "pieces " << pieces << " shards " << shards;
        last = s;
        ++count[s];
      }
      for (std::uint32_t s = 0; s < shards && shards <= pieces; ++s) {
        EXPECT_GE(count[s], static_cast<int>(pieces / shards));
        EXPECT_LE(count[s], static_cast<int>((pieces + shards - 1) / shards));
      }
    }
  }
}

TEST(Pieces, CorruptAndMalformedFilesAreNamed) {
  const PointSet points = make_points(3, uniform_points(3, 1500, 3));
  TempDir dir;
  PieceOptions options;
  options.piece_points = 400;
  auto m = store_pieces(points, "s", dir.str(), options);
  ASSERT_TRUE(m.is_ok());
  const std::string path = pieces_dir(dir.str(), "s") + "/1.piece";
  std::string bytes = read_file(path);
  bytes[bytes.size() / 2] ^= 0x10;
  { std::ofstream(path, std::ios::binary) << bytes; }
  auto bad = read_piece(path, m.value(), 1);
  ASSERT_FALSE(bad.is_ok());
  EXPECT_NE(bad.status().message().find("1.piece: corrupt piece file: CRC-32"), std::string::npos)
      << bad.status().message();
  bytes.pop_back();
  { std::ofstream(path, std::ios::binary) << bytes; }
  EXPECT_NE(read_piece(path, m.value(), 1).status().message().find("bytes, the manifest says"), std::string::npos);
  EXPECT_EQ(read_piece(path + "x", m.value(), 1).status().code(), Code::kNotFound);

  std::string text = manifest_text(m.value());
  auto broken = parse_manifest(text.substr(0, text.size() - 40), "M");
  ASSERT_FALSE(broken.is_ok());
  EXPECT_EQ(broken.status().message().rfind("M:", 0), 0u) << broken.status().message();
  EXPECT_FALSE(parse_manifest("hello\n", "M").is_ok());
  // A second store of the same set leaves the layout and returns it.
  auto again = store_pieces(points, "s", dir.str(), options);
  ASSERT_TRUE(again.is_ok());
  EXPECT_EQ(manifest_text(again.value()), manifest_text(m.value()));
}

}  // namespace
}  // namespace spokemesh
