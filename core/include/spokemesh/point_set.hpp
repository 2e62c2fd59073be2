// PointSet: n points in R^d, coordinates contiguous and row-major.
//
// A PointSet that passed validate() is what every other core module assumes:
// d in [2, kMaxDimension], n >= d + 1, finite coordinates with |x| <= kMaxCoordinate,
// no two equal points, and an affine span of full dimension d. It also carries the
// lexicographic rank of each point, which keys the symbolic perturbation
// (Devillers & Teillaud 2011): among tied points, the lexicographically larger
// one counts as lifted higher, i.e. as outside.
//
// Ownership: owns its coordinates. Thread safety: immutable after validate();
// concurrent reads are safe.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "spokemesh/status.hpp"

namespace spokemesh {

// Largest dimension for exact meshing. The predicates' subset tables are sized
// 2^(d+1), and Delaunay stars beyond d = 8 are too large to enumerate anyway.
inline constexpr int kMaxDimension = 8;
// Largest dimension any input may have: approximate neighbour graphs (approx.hpp) go
// this far; readers refuse more, naming the file.
inline constexpr int kMaxApproxDimension = 1024;
// Largest accepted |coordinate|. Exact arithmetic (GMP) has no limit; this bound
// keeps the floating-point candidate distances finite (d * (2e100)^2 < 1e300).
inline constexpr double kMaxCoordinate = 1e100;

class PointSet {
 public:
  PointSet() = default;
  PointSet(int dimension, std::vector<double> coordinates);

  int dimension() const { return d_; }
  std::size_t size() const { return d_ == 0 ? 0 : coords_.size() / static_cast<std::size_t>(d_); }
  const double* point(std::size_t i) const { return coords_.data() + i * static_cast<std::size_t>(d_); }
  std::span<const double> coordinates() const { return coords_; }

  // Lexicographic rank of point i (0 = smallest); valid after validate().
  std::uint32_t lex_rank(std::size_t i) const { return rank_[i]; }

  // The common binary scale of the coordinates, set by validate(): every coordinate
  // is an integer times 2^scale_exponent() of at most integer_bits() bits. Every
  // double is m 2^e with an integer m, so one scale turns any grid (integer,
  // dyadic, linspace or decimal steps) into integers; the exact predicates work on
  // those integers (converted once per set, not per call). kNoIntegerScale before
  // validate() or when all coordinates are zero.
  static constexpr int kNoIntegerScale = 1 << 20;
  int scale_exponent() const { return scale_exponent_; }
  int integer_bits() const { return integer_bits_; }

  // Checks the preconditions above (duplicates are refused here; merge them first
  // with merge_duplicates()). `source` names the input in messages ("file.txt").
  // check_span = false skips the exact affine-rank check (approximate neighbour
  // graphs do not need full dimension, and in high d that check is the costly part).
  Status validate(const std::string& source, int max_dimension = kMaxDimension, bool check_span = true);
  // validate() for a set whose first points are `parent`'s (validated, with the same
  // dimension): only the points after them are checked, and the lexicographic ranks
  // come from merging them, sorted, into the parent's order (O(n) rather than a sort of
  // all n); the span is the parent's or larger. The same state and the same first
  // error as validate() gives.
  Status validate_appended(const PointSet& parent, const std::string& source);

  // Removes exact duplicates, keeping each first occurrence. Returns for every
  // input index the index it maps to in the reduced set. Precondition: finite
  // coordinates (the readers refuse others).
  std::vector<std::uint32_t> merge_duplicates();

  // Indices of points that span the set's affine hull: the first point, then each point
  // that raises the rank of the differences from it (exact, over the rationals); at
  // most d + 1. The hull of a union of parts is spanned by the union of the parts'
  // bases, which is how a distributed run checks full dimension.
  std::vector<std::uint32_t> affine_basis() const;
  // INVALID_ARGUMENT unless n points of dimension d are enough for a mesh (d + 1) and
  // few enough for 32-bit indices (validate's count check, for callers that hold a part
  // of a set).
  static Status check_count(std::uint64_t n, int d, const std::string& source);
  // INVALID_ARGUMENT unless the points span R^d (validate's last check).
  Status check_affine_span(const std::string& source) const;

 private:
  // The state validate() leaves: ranks from a lexicographic order, and the integer
  // scale from the binary span [lowest, highest] of all coordinates.
  void set_ranks_and_scale(const std::vector<std::uint32_t>& order, int lowest, int highest);

  int d_ = 0;
  std::vector<double> coords_;
  std::vector<std::uint32_t> rank_;
  int scale_exponent_ = 0;
  int integer_bits_ = kNoIntegerScale;
};

// Widens [lowest, highest] to v's binary span: v = m 2^lowest for an integer m, and
// |v| < 2^highest (zero changes nothing). Used for the common integer scale of a set
// and of a spoke direction.
void widen_binary_span(double v, int& lowest, int& highest);

// Lexicographic comparison of two points of dimension d (exact on doubles).
bool lex_less(const double* a, const double* b, int d);

}  // namespace spokemesh
