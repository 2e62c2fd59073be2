// Pieces: a point set kept as the nodes of its SpaceSplit, each with the halo its
// seeds need, so that a server holding a few pieces answers their seeds' stars,
// neighbours and cells with the same bytes as one holding the whole set
// (docs/service.md, "Sharded serving").
//
// The layout is a function of the set alone: the pieces are the maximal nodes of the
// whole set's split (leaf SpaceSplit::kLeafPoints) holding at most `piece_points`
// points, in sweep order. Piece p holds its own points and a halo:
//   - every Delaunay neighbour of every one of its points (the 1-ring): the star of a
//     point computed from any subset holding all its neighbours is its star in the
//     whole set (each simplex of the whole star has an empty circumsphere in the
//     subset, and the whole star already covers a neighbourhood of the seed, hull
//     facets included), so stars, neighbours and unclipped cells need no certificate;
//   - every point inside its held box: the piece's tight box grown by kHaloSpacings
//     mean spacings of its points (clipped to the set's box), so that a clipped cell,
//     which the builder decides from the points within a reach of the seed, is certified
//     when that ball's part inside the set's box lies in the held box; a cell whose
//     ball does not is completed from the other pieces' files by the server.
//
// Files (the server's data directory, docs/service.md):
//   pieces/<set id>/manifest     text: the layout, every piece's boxes, sizes and CRC-32
//   pieces/<set id>/owners       uint32 LE per point: the piece holding it (the router's map)
//   pieces/<set id>/<p>.piece    binary (write_piece below)
// The directory is written under a temporary name and renamed into place, so a reader
// sees a whole layout or none. Every writer (one process, or spokemesh-mpi's ranks)
// produces the same bytes.
//
// Thread safety: functions are reentrant; the types are plain values.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "spokemesh/point_set.hpp"
#include "spokemesh/star.hpp"
#include "spokemesh/status.hpp"
#include "spokemesh/voronoi.hpp"

namespace spokemesh {

// Points a piece holds at most by default: 2^21 (a 20M-point set: 16 pieces of 1.25M).
constexpr std::uint32_t kDefaultPiecePoints = 1u << 21;
// The held box's depth around a piece's box, in mean spacings of its points.
constexpr double kHaloSpacings = 3.0;

// The shard serving piece p of `pieces` among `shards`: contiguous runs in sweep order
// (so a shard's pieces are neighbours in space and in a stream), shard k holding pieces
// [ceil(k P / S), ceil((k + 1) P / S)). Preconditions: piece < pieces, shards >= 1.
inline std::uint32_t shard_of_piece(std::uint32_t piece, std::uint32_t pieces, std::uint32_t shards) {
  return static_cast<std::uint32_t>((std::uint64_t{piece} * shards) / pieces);
}

// The held box of a piece whose own points' tight box is `box` (d lows, d highs) and
// which holds `count` points, in a set whose box is `global_box`: the box grown by
// kHaloSpacings mean spacings ((volume / count)^(1/d), or the widest side over
// count^(1/d) when the box is flat), clipped to the set's box.
std::vector<double> held_box_of(std::span<const double> box, std::uint64_t count, std::span<const double> global_box);

// Whether point p lies in the closed box (d lows, d highs): the held box's rule, the
// same for every writer of pieces and for the server's completed cells.
inline bool in_box(std::span<const double> box, const double* p) {
  const std::size_t d = box.size() / 2;
  for (std::size_t c = 0; c < d; ++c) {
    if (p[c] < box[c] || p[c] > box[d + c]) return false;
  }
  return true;
}

struct PieceEntry {
  std::uint64_t start = 0;       // first sweep position
  std::uint64_t count = 0;       // own points
  std::uint64_t held = 0;        // own + halo
  std::vector<double> box;       // own points' tight box (d lows, d highs)
  std::vector<double> held_box;  // every point of the set inside is held
  std::uint32_t crc = 0;         // CRC-32 of the piece file
  std::uint64_t bytes = 0;       // size of the piece file
};

struct PieceManifest {
  std::string set_id;
  int dimension = 0;
  std::uint64_t count = 0;
  std::uint32_t piece_points = 0;
  std::vector<double> global_box;
  std::vector<PieceEntry> pieces;
};

// One piece as held: its points and halo in ascending global index order (so that
// every comparison of indices is the whole set's), with a flag for its own points.
struct Piece {
  std::uint32_t index = 0;
  int dimension = 0;
  std::uint64_t set_count = 0;
  std::uint64_t start = 0;
  std::vector<std::uint64_t> ids;  // ascending
  std::vector<std::uint8_t> own;   // 1: one of the piece's own points; 0: halo
  std::vector<double> coords;      // d per held point, in ids' order
  std::vector<double> box, held_box;
  std::uint64_t own_count() const;
};

// The manifest as text (doubles as %.17g: exact) and back. parse_manifest names the
// line of anything malformed (`source` names the file).
std::string manifest_text(const PieceManifest& manifest);
Result<PieceManifest> parse_manifest(const std::string& text, const std::string& source);

// A piece file: "SMPIECE1", then little-endian u32 d, index, pieces, 0; u64 set count,
// start, own count, held count; 2 d f64 box, 2 d f64 held box; held u64 ids; held u8
// flags; held d f64 coordinates; u32 CRC-32 of everything before it.
std::string piece_bytes(const Piece& piece, std::uint32_t pieces);
// Reads and checks a piece file against its manifest entry (size, CRC-32, shape).
// NOT_FOUND when missing; DATA_LOSS-like INVALID_ARGUMENT naming the file when corrupt.
Result<Piece> read_piece(const std::string& path, const PieceManifest& manifest, std::uint32_t index);

// Writes `bytes` to `path` durably: a temporary file beside it, fsynced, renamed.
Status write_file_durably(const std::string& path, const std::string& bytes);

struct PieceOptions {
  std::uint32_t piece_points = kDefaultPiecePoints;
  unsigned threads = 1;
  const std::atomic<bool>* cancel = nullptr;  // stops the run (CANCELLED)
};

// Cuts a validated 2-d or 3-d, unweighted, non-periodic set into pieces and writes
// them with their manifest and owner map to `dir`/pieces/`set_id`/, atomically (a
// temporary directory renamed into place; an existing layout is left as it is and
// returned). Holds the set's whole mesh's halo lists while it runs, not the mesh.
Result<PieceManifest> store_pieces(const PointSet& points, const std::string& set_id, const std::string& dir,
                                   const PieceOptions& options);

// A piece's held points as a PointSet whose index k is the piece's k-th held point
// (validated; INVALID_ARGUMENT when they do not span the space). Answers computed on
// it are the whole set's once mapped back with to_global: local order is global order.
Result<PointSet> piece_point_set(const Piece& piece);
// The local index of global index `id` in a piece's ascending ids, or kNotHeld.
constexpr std::uint32_t kNotHeld = 0xFFFFFFFFu;
std::uint32_t local_index(std::span<const std::uint64_t> ids, std::uint64_t id);
// Local indices of a star or a cell replaced by the global ones (ids: ascending).
void to_global(Star& star, std::span<const std::uint64_t> ids);
void to_global(VoronoiCell& cell, std::span<const std::uint64_t> ids);

// The directory of a set's pieces, and reading its manifest (NOT_FOUND when absent).
std::string pieces_dir(const std::string& dir, const std::string& set_id);
Result<PieceManifest> read_manifest(const std::string& dir, const std::string& set_id);

}  // namespace spokemesh
