#include "spokemesh/star.hpp"

#include "spokemesh/periodic_cover.hpp"

#include <algorithm>
#include <array>
#include <cstring>
#include <limits>
#include <numeric>

#include "base/dimension.hpp"
#include "base/invariant.hpp"
#include "base/mixing.hpp"
#include "base/simd.hpp"
#include "walks/ring_walk.hpp"

namespace spokemesh {
namespace {

constexpr int kMaxCols = kMaxDimension + 1;
using filter::is_certifiable;
using filter::relative_error;
constexpr double kInf = std::numeric_limits<double>::infinity();
// Sphere queries that found a point missing from the candidates before the walk
// loads a neighbourhood twice as large (once per seed: a seed on the hull can have
// spheres of any size, and the tree answers those). Measurements behind this and the
// other constants: bench/README.md, "Tuning history".
constexpr int kGrowAfterMisses = 3;
// A k-NN search is bounded by the previous seed's k-th squared distance times this.
constexpr double kGuessSlack = 1.5;
// FacetCache entries a walker reserves at a time (one shared counter update per batch).
constexpr std::size_t kCacheBatch = 256;
// Candidates per chunk of the pencil scan's vectorized dot products.
constexpr std::size_t kPencilChunk = 16;

// Certified sign of a dot product v = sum coefficient_c q_c computed in double, whose
// monomial magnitudes sum to a, at the given rounding depth (of the coefficients plus
// the dot product's own d + 1 roundings); kUnknownSign when not certain. Its last
// products are not BoundedDouble products, so the underflow guard is applied to their
// sum a (filter::is_certifiable): smaller magnitudes go to the exact stage, which
// also keeps slow subnormal arithmetic off the hot path.
inline int certified(double v, double a, int depth) {
  if (depth >= BoundedDouble::kUnsafe) return BoundedDouble::kUnknownSign;
  return filter::certified_sign(v, a, depth + 1);
}

// One wrap's pencil (see WrapState::pencil_scan, step 1a): the rotation's vertical normal nn
// and reference plane h, with the magnitudes and depths of their error bounds.
struct Pencil {
  const double* nn;  // d coefficients
  const double* h;   // d + 1 coefficients
  double n_mag, h_mag, h_mag_d;
  double n_eps;         // relative error factor of nn . q
  double h_depth_base;  // rounding depth of h(q), less the candidate's height depth
  std::size_t mag_row;  // the block's row of height magnitudes (the height row itself when unweighted)
};

using detail::Double2;
using detail::Double4;
using detail::Mask2;
using detail::Mask4;

// The pencil scan's filter for kPencilChunk candidates stored column-major in
// `block` (d coordinate rows, then the height, |q|, the height's depth and, with
// weights, its magnitude; rows `stride` apart). Writes nv_j = nn . q_j and
// hv_j = h_d height_j + h . q_j, summed in the
// same order as a row-by-row loop, and the offsets of the first `limit` candidates
// that can still be the first hit to `keep`; returns their number. Rejected are only
// candidates certainly on the wrong side (nn . q < 0) or certainly met after u_best
// (certified lambda_c > u_best), with the bounds of the scalar scan in WrapState::pencil_scan;
// anything uncertain is kept for it. Branch-free, V's lanes at a time; the same
// operations in the same order for any lane count, so the results are bit-identical.
template <int D, class V, class M>
[[gnu::always_inline]] inline std::size_t pencil_filter_lanes(const double* block, std::size_t stride,
                                                              const Pencil& pencil, double u_best, std::size_t limit,
                                                              double* nv, double* hv, std::uint8_t* keep) {
  constexpr std::size_t kLanes = sizeof(V) / sizeof(double);
  static_assert(kPencilChunk % kLanes == 0);
  const double* heights = block + D * stride;
  const double* norm = heights + stride;
  const double* depth = norm + stride;
  const double* magnitude = block + pencil.mag_row * stride;
  std::array<std::int64_t, kPencilChunk> reject;
  for (std::size_t i = 0; i < kPencilChunk; i += kLanes) {
    V q, qh, qh_mag, qn, qdepth;  // loaded by memcpy: rows need not be aligned
    std::memcpy(&q, block + i, sizeof q);
    std::memcpy(&qh, heights + i, sizeof qh);
    std::memcpy(&qh_mag, magnitude + i, sizeof qh_mag);
    std::memcpy(&qn, norm + i, sizeof qn);
    std::memcpy(&qdepth, depth + i, sizeof qdepth);
    V n = pencil.nn[0] * q;
    V h = pencil.h[D] * qh + pencil.h[0] * q;
    for (int c = 1; c < D; ++c) {
      std::memcpy(&q, block + static_cast<std::size_t>(c) * stride + i, sizeof q);
      n += pencil.nn[c] * q;
      h += pencil.h[c] * q;
    }
    std::memcpy(nv + i, &n, sizeof n);
    std::memcpy(hv + i, &h, sizeof h);
    const V n_bound = pencil.n_mag * qn;
    const V en = n_bound * pencil.n_eps;
    const V h_bound = pencil.h_mag_d * qh_mag + pencil.h_mag * qn;
    // filter::relative_error and filter::is_certifiable, per lane (test_predicates'
    // Filter test checks that these lanes compute what the scalar filter does).
    const V eh = h_bound * ((pencil.h_depth_base + qdepth + filter::kDepthSlack) * filter::kErrorPerLevel);
    const V h_low = h - eh;
    const V lo_num = (h_low > 0 ? h_low : 0.0) * (1 - 1e-12), lo_den = n + en;
    const M n_safe = (n_bound >= filter::kUnderflowGuard) & (n_bound <= DBL_MAX);
    const M h_safe = (h_bound >= filter::kUnderflowGuard) & (h_bound <= DBL_MAX);
    const M wrong_side = n < -en;
    const M after_best = h_safe & (lo_den > 0) & (lo_num > u_best * lo_den * (1 + 1e-15));
    const M r = n_safe & (wrong_side | after_best);
    for (std::size_t k = 0; k < kLanes; ++k) reject[i + k] = r[k];
  }
  std::size_t kept = 0;
  for (std::size_t i = 0; i < limit; ++i) {
    keep[kept] = static_cast<std::uint8_t>(i);
    kept += reject[i] == 0 ? 1 : 0;
  }
  return kept;
}

template <int D>
std::size_t pencil_filter_sse2(const double* block, std::size_t stride, const Pencil& pencil, double u_best,
                               std::size_t limit, double* nv, double* hv, std::uint8_t* keep) {
  return pencil_filter_lanes<D, Double2, Mask2>(block, stride, pencil, u_best, limit, nv, hv, keep);
}

template <int D>
SPOKEMESH_TARGET_AVX2 std::size_t pencil_filter_avx2(const double* block, std::size_t stride, const Pencil& pencil,
                                                     double u_best, std::size_t limit, double* nv, double* hv,
                                                     std::uint8_t* keep) {
  return pencil_filter_lanes<D, Double4, Mask4>(block, stride, pencil, u_best, limit, nv, hv, keep);
}

using PencilFilter = std::size_t (*)(const double*, std::size_t, const Pencil&, double, std::size_t, double*, double*,
                                     std::uint8_t*);

// The widest filter this CPU runs (same bits either way: simd.hpp).
template <int D>
PencilFilter pencil_filter() {
  return detail::has_avx2() ? &pencil_filter_avx2<D> : &pencil_filter_sse2<D>;
}

// Uniform in [-1, 1), exactly representable (53 random bits).
double random_unit(std::uint64_t& state) {
  return static_cast<double>(detail::splitmix64(state) >> 11) * 0x1p-52 - 1.0;
}

}  // namespace

std::size_t default_candidates(int d) {
  // Enough that most wraps are decided by the candidates, few enough that loading
  // them stays cheap.
  return detail::policy(d).candidates;
}

// ---------------------------------------------------------------------------------
// TupleSet

void StarWalker::TupleSet::reset(int length) {
  length_ = length;
  count_ = 0;
  keys_.clear();
  if (slots_.empty()) slots_.assign(256, 0);
  // A new generation empties every slot at once; only when the counter wraps (every
  // 65,535 seeds) are the slots cleared.
  if (++generation_ == (std::uint64_t{1} << (64 - kGenerationShift))) {
    std::fill(slots_.begin(), slots_.end(), 0);
    generation_ = 1;
  }
}

std::uint64_t StarWalker::TupleSet::hash(const std::uint32_t* key) const {
  return detail::hash_indices(key, static_cast<std::size_t>(length_));
}

void StarWalker::TupleSet::grow() {
  slots_.assign(slots_.size() * 2, 0);
  const std::size_t mask = slots_.size() - 1;
  const std::uint64_t live = generation_ << kGenerationShift;
  for (std::size_t i = 0; i < count_; ++i) {
    const std::uint64_t h = hash(&keys_[i * length_]);
    std::size_t s = h & mask;
    while ((slots_[s] >> kGenerationShift) == generation_) s = (s + 1) & mask;
    slots_[s] = live | (h & kTagMask) | (i + 1);
  }
}

void StarWalker::TupleSet::prefetch(std::uint64_t h) const { __builtin_prefetch(&slots_[h & (slots_.size() - 1)]); }

bool StarWalker::TupleSet::insert(const std::uint32_t* key) { return insert(key, hash(key)); }

bool StarWalker::TupleSet::insert(const std::uint32_t* key, std::uint64_t h) {
  bool inserted = false;
  position(key, h, inserted);
  return inserted;
}

std::uint32_t StarWalker::TupleSet::position(const std::uint32_t* key, std::uint64_t h, bool& inserted) {
  if (2 * (count_ + 1) > slots_.size()) grow();
  const std::size_t mask = slots_.size() - 1;
  const std::uint64_t live = generation_ << kGenerationShift;
  const std::uint64_t tag = h & kTagMask;
  std::size_t s = h & mask;
  // A slot holds a tag from the key's hash beside its position: only a matching tag
  // (a duplicate, or one chance in 65,536) reads the key itself, which in 6-d stars
  // of 30,000 facets is a cache miss.
  for (std::uint64_t slot = slots_[s]; (slot >> kGenerationShift) == generation_; slot = slots_[s]) {
    if ((slot & kTagMask) == tag) {
      const std::uint32_t at = static_cast<std::uint32_t>((slot & kPositionMask) - 1);
      if (detail::same_indices(key, &keys_[at * static_cast<std::size_t>(length_)],
                               static_cast<std::size_t>(length_))) {
        inserted = false;
        return at;
      }
    }
    s = (s + 1) & mask;
  }
  slots_[s] = live | tag | (count_ + 1);
  keys_.insert(keys_.end(), key, key + length_);
  inserted = true;
  return static_cast<std::uint32_t>(count_++);
}

// ---------------------------------------------------------------------------------
// StarWalker

StarWalker::StarWalker(const KdTree& tree, StarOptions options)
    : tree_(tree),
      ps_(tree.points()),
      predicates_(ps_, options.weights, options.cover != nullptr ? &options.cover->box() : nullptr,
                  options.cover != nullptr ? options.cover->images() : ImageMap{}),
      options_(options),
      d_(ps_.dimension()),
      extras_{options.weights.empty() ? nullptr : options.weights.data(),
              options.cover != nullptr ? &options.cover->box() : nullptr, nullptr,
              options.cover != nullptr ? options.cover->images() : ImageMap{}} {
  SPOKEMESH_INVARIANT(options.weights.empty() || options.weights.size() == ps_.size(),
                      "one weight per point of the tree");
  SPOKEMESH_INVARIANT(options.cover == nullptr || &options.cover->tree() == &tree,
                      "a periodic cover's walker walks its tree");
  if (options.cover != nullptr) {
    image_first_ = options.cover->point_count();
    image_pad_ = options.cover->pad();
  }
  if (!options.weights.empty()) max_weight_ = *std::max_element(options.weights.begin(), options.weights.end());
  if (detail::policy(d_).ring_walk) ring_walk_ = std::make_unique<RingWalk>(*this);
  // The walker's one dispatch from the runtime dimension to its compiled kernels.
  detail::dispatch_dimension(d_, [&](auto dim) {
    constexpr int D = decltype(dim)::value;
    if constexpr (D >= 2) kernels_ = {&StarWalker::wrap_kernel<D>, &StarWalker::simplex_plane_kernel<D>};
  });
  minors_.resize(std::size_t{1} << (d_ + 1));
  directions_.resize(static_cast<std::size_t>(d_ * d_));
}

StarWalker::~StarWalker() = default;

void StarWalker::load_candidates(std::size_t k) {
  ++stats_.candidate_loads;
  const std::size_t n = ps_.size();
  const std::size_t want = std::min(k + 1, n);  // +1: the seed finds itself
  knn_ids_.resize(want);
  knn_d2_.resize(want);
  knn_coords_.resize(want);
  // Seeds come in an order that keeps neighbours close (a whole mesh walks the tree's
  // leaf order), so the last seed's k-th distance, with room to spare, bounds this
  // one's: the search then skips every box beyond it. Too tight a guess (fewer than
  // k points inside it) only costs a second, unbounded search.
  const bool initial = !loaded_;  // not the enlarged neighbourhood of a near-hull seed
  const double guess2 = initial ? knn_guess2_ * kGuessSlack : kInf;
  std::size_t got = tree_.knn(ps_.point(x_), want, knn_ids_.data(), knn_d2_.data(), knn_coords_.data(), guess2);
  if (got < want && guess2 < kInf) {
    got = tree_.knn(ps_.point(x_), want, knn_ids_.data(), knn_d2_.data(), knn_coords_.data());
  }
  if (initial && got == want) knn_guess2_ = knn_d2_[got - 1];
  std::size_t kept = 0;
  for (std::size_t i = 0; i < got; ++i) kept += knn_ids_[i] != x_ ? 1 : 0;
  // Sized once, then written in place (this runs for nearly every seed).
  cand_id_.resize(kept);
  cand_q_.resize(kept * d_);
  cand_height_.resize(kept);
  cand_height_mag_.resize(kept);
  cand_norm_.resize(kept);
  cand_depth_.resize(kept);
  cand_lower_.resize(kept);
  // Column-major copy for the pencil scan's filter (d coordinate rows, the height,
  // |q|, the height's depth with kUnsafe as +inf and, with weights, the height's
  // magnitude), zero-padded to whole chunks (padding is never a candidate: the scan
  // stops at `kept`).
  cand_stride_ = (kept + kPencilChunk - 1) / kPencilChunk * kPencilChunk;
  const std::size_t rows = static_cast<std::size_t>(d_) + (extras_.weights != nullptr ? 4 : 3);
  cand_block_.resize(cand_stride_ * rows);
  for (std::size_t r = 0; r < rows; ++r) {
    std::fill(cand_block_.begin() + static_cast<std::ptrdiff_t>(r * cand_stride_ + kept),
              cand_block_.begin() + static_cast<std::ptrdiff_t>((r + 1) * cand_stride_), 0.0);
  }
  std::size_t j = 0;
  for (std::size_t i = 0; i < got; ++i) {
    const std::uint32_t id = knn_ids_[i];
    if (id == x_) continue;
    double* q = &cand_q_[j * d_];
    const Lift lift = relative_row(id, knn_coords_[i], q);
    cand_id_[j] = id;
    cand_height_[j] = lift.height;
    cand_height_mag_[j] = lift.magnitude;
    cand_norm_[j] = std::sqrt(lift.norm2);
    cand_depth_[j] = lift.depth;
    cand_lower_[j] = knn_d2_[i] * (1 - kDistanceMargin);
    if (image_pad_ > 0) {
      // Bounds for every candidate from this one on, in the tree's order: images may
      // lie up to image_pad_ per axis nearer than their stored coordinates.
      const double r = std::max(0.0, std::sqrt(knn_d2_[i]) - 2 * image_pad_ * std::sqrt(static_cast<double>(d_)));
      cand_lower_[j] = r * r * (1 - kDistanceMargin);
    }
    double* column = &cand_block_[j];
    for (int c = 0; c < d_; ++c) column[static_cast<std::size_t>(c) * cand_stride_] = q[c];
    column[static_cast<std::size_t>(d_) * cand_stride_] = lift.height;
    column[static_cast<std::size_t>(d_ + 1) * cand_stride_] = cand_norm_[j];
    column[static_cast<std::size_t>(d_ + 2) * cand_stride_] = lift.depth >= BoundedDouble::kUnsafe ? kInf : lift.depth;
    if (extras_.weights != nullptr) column[static_cast<std::size_t>(d_ + 3) * cand_stride_] = lift.magnitude;
    ++j;
  }
  r2_certified_ = (got == n) ? kInf : knn_d2_[got - 1] * (1 - kDistanceMargin);
  if (image_pad_ > 0 && r2_certified_ != kInf) {
    // Points not loaded may be images, whose exact positions lie up to image_pad_ per
    // axis nearer than the tree measured.
    const double r = std::max(0.0, std::sqrt(r2_certified_) - 2 * image_pad_ * std::sqrt(static_cast<double>(d_)));
    r2_certified_ = r * r * (1 - kDistanceMargin);
  }
}

void StarWalker::relative(std::uint32_t id, const double* pp, double* q) const {
  const double* x = ps_.point(x_);
  if (id < image_first_) {
    for (int c = 0; c < d_; ++c) q[c] = pp[c] - x[c];
    return;
  }
  const PeriodicCover& cover = *options_.cover;
  const double* p = ps_.point(cover.point_of(id));
  const std::int32_t* k = cover.offset_of(id);
  const auto& lo = cover.box().lo();
  const auto& hi = cover.box().hi();
  for (int c = 0; c < d_; ++c) {
    q[c] = image_difference(p[c], k[c], lo[static_cast<std::size_t>(c)], hi[static_cast<std::size_t>(c)], x[c]);
  }
}

StarWalker::Lift StarWalker::relative_row(std::uint32_t id, const double* pp, double* q) const {
  relative(id, pp, q);
  double norm2 = 0;
  for (int c = 0; c < d_; ++c) norm2 += q[c] * q[c];
  // A sum of d squares of rounded differences has depth d + 2; one more covers a
  // square that underflowed (absolute error 2^-1075, relatively negligible once
  // the magnitude is >= 2^-900). Below that, the exact stage decides.
  if (extras_.weights == nullptr) {
    return {norm2, norm2, norm2, norm2 >= filter::kUnderflowGuard ? d_ + 3 : BoundedDouble::kUnsafe};
  }
  // With weights, as approx_row: the weights' difference rounded once (depth 1) and
  // subtracted once (one level more than the sum of squares).
  const double excess = extras_.weights[id] - extras_.weights[x_];
  const double magnitude = norm2 + std::fabs(excess);
  return {norm2, norm2 - excess, magnitude, magnitude >= filter::kUnderflowGuard ? d_ + 4 : BoundedDouble::kUnsafe};
}

void StarWalker::lifted_row(const double* q, const Lift& lift, BoundedDouble* out) const {
  for (int c = 0; c < d_; ++c) out[c] = BoundedDouble{q[c], std::fabs(q[c]), 1};  // one rounding: p - x
  out[d_] = BoundedDouble{lift.height, lift.magnitude, lift.depth};
}

double StarWalker::exit_estimate(double slope2) const {
  if (weight_excess_ == 0) return slope2 * (1 + 1e-9);
  const double reach = std::sqrt(slope2) + std::sqrt(weight_excess_);
  return reach * reach * (1 + 1e-9);
}

StarWalker::WrapResult StarWalker::wrap(const Row* pivot, Side side, const BoundedDouble* reference,
                                        BoundedDouble* hit_plane) {
  return (this->*kernels_.wrap)(pivot, side, reference, hit_plane);
}

// One wrap of StarWalker::wrap_kernel: its state and its steps, in the order the
// kernel runs them. Everything a step shares with another lives here, so each step
// reads on its own; the walker's candidate arrays, caches and counters are read
// through `w` (a nested class: the walker's private members are its own).
template <int D>
class StarWalker::WrapState {
 public:
  static constexpr int d = D;
  static constexpr int cols = D + 1;
  static constexpr unsigned all = (1u << cols) - 1u;

  WrapState(StarWalker& walker, const Row* pivot_rows) : w(walker), pivot(pivot_rows), x(walker.ps_.point(walker.x_)) {}

  // 0. The minors of the pivot rows, shared by the spatial normal and every lifted
  //    plane; the spatial normal: side(q) = sign(sum_c normal_c q_c) = sign det[pivot; q].
  void pivot_minors() {
    std::array<BoundedDouble, (D - 1) * (D + 1)> pivot_table;
    for (int r = 0; r < d - 1; ++r) approx_row(w.ps_, w.x_, pivot[r], cols, &pivot_table[r * cols], w.extras_);
    minors_table_fixed<D - 1, D + 1>(pivot_table.data(), w.minors_.data());
    constexpr unsigned spatial = (1u << d) - 1u;
    normal_depth = 0;
    for (int c = 0; c < d; ++c) {
      const BoundedDouble& m = w.minors_[spatial ^ (1u << c)];
      normal[c] = ((d - 1 + c) % 2 == 0) ? m : -m;
      normal_depth = std::max(normal_depth, normal[c].depth);
    }
    std::copy(pivot, pivot + d - 1, rows.begin());
  }

  // The side of the pivot's spatial hyperplane the wrap turns to (sigma).
  void orient(Side side) {
    if (side.away_from >= 0) {
      std::array<double, kMaxDimension> q;
      const auto o = static_cast<std::uint32_t>(side.away_from);
      w.relative(o, w.ps_.point(o), q.data());
      sigma = -spatial_side(q.data(), static_cast<std::uint32_t>(side.away_from));
    } else {
      // Towards the spoke direction (exact doubles, so one rounding less than q).
      double v = 0, a = 0;
      for (int c = 0; c < d; ++c) {
        v += normal[c].value * side.toward[c];
        a += normal[c].magnitude * std::fabs(side.toward[c]);
      }
      sigma = certified(v, a, normal_depth + d + 2);
      if (sigma == BoundedDouble::kUnknownSign) {
        rows[d - 1] = Row::of_direction(side.toward);
        sigma = w.predicates_.spatial_sign_exact(w.x_, std::span<const Row>(rows.data(), d));
      }
      sigma *= side.reverse ? -1 : 1;
    }
    SPOKEMESH_INVARIANT(sigma == 1 || sigma == -1, "a wrap's side must be strict (the pivot spans a hyperplane)");
  }

  // 1a. The pencil scan. Every hyperplane through the lifted pivot (and x) is
  //     h - lambda (n, 0): h the plane through the pivot and a reference row that
  //     every point is on or above (the simplex being left, or for a spoke the
  //     previous level's plane through the spoke direction; the tangent plane at x
  //     at level 0), n = sigma * normal the vertical one. Rotating towards side sigma
  //     meets candidate c at lambda_c = h(c) / n(c), so the first hit is the least
  //     lambda_c: one floating-point key per candidate, bracketed by certified error
  //     bounds, instead of a plane rebuilt at every improvement. Only candidates whose
  //     brackets reach below the best upper bound are compared exactly afterwards.
  //     Sums of |coefficient| * |q_c| are bounded by Cauchy-Schwarz, ||coeff|| |q|.
  //     Leaves `next` at the first candidate the certified scan must still look at.
  void pencil_scan(const BoundedDouble* reference) {
    int h_depth = 0;
    for (int c = 0; c < cols; ++c) h_depth = std::max(h_depth, reference[c].depth);
    const int up = reference[d].certified_sign();
    if (!(up == 1 || up == -1) || h_depth >= BoundedDouble::kUnsafe || normal_depth >= BoundedDouble::kUnsafe) return;
    std::array<double, kMaxCols> h;
    std::array<double, kMaxDimension> nn;
    double h_mag2 = 0, n_mag2 = 0;
    for (int c = 0; c < d; ++c) {
      h[c] = up * reference[c].value;
      nn[c] = sigma * normal[c].value;
      h_mag2 += reference[c].magnitude * reference[c].magnitude;
      n_mag2 += normal[c].magnitude * normal[c].magnitude;
    }
    h[d] = up * reference[d].value;
    const double h_mag_d = reference[d].magnitude;
    const double h_mag = std::sqrt(h_mag2) * (1 + 1e-12), n_mag = std::sqrt(n_mag2) * (1 + 1e-12);
    // certified()'s error factors for the two dot products (see spatial_side and
    // lifted_side; candidates with an unsafe |q|^2 depth are left to 1b).
    const double n_eps = relative_error(normal_depth + d + 3 + 1);
    // h(q)'s rounding depth is h_depth_base + the candidate's |q|^2 depth.
    const int h_depth_base = h_depth + d + 4 + 1;
    double u_best = kInf;
    std::int64_t best_j = -1;
    w.contenders_.clear();
    const std::size_t mag_row = static_cast<std::size_t>(w.extras_.weights != nullptr ? d + 3 : d);
    const Pencil pencil{nn.data(), h.data(), n_mag, h_mag, h_mag_d, n_eps, static_cast<double>(h_depth_base), mag_row};
    const PencilFilter filter = pencil_filter<D>();
    std::array<double, kPencilChunk> nvs, hvs;
    std::array<std::uint8_t, kPencilChunk> keep;
    const std::size_t count = w.cand_id_.size();
    // Chunk by chunk: the filter rejects most candidates branch-free; the rest are
    // bracketed one by one. Every candidate before `next` is a contender or certainly
    // not the first hit, which is all step 1b relies on.
    bool stopped = false;
    while (next < count && !stopped) {
      if (best_j >= 0 && w.cand_lower_[next] > next_exit_test) break;  // estimate; certified below
      const std::size_t chunk = next, limit = std::min(kPencilChunk, count - next);
      const std::size_t kept =
          filter(&w.cand_block_[chunk], w.cand_stride_, pencil, u_best, limit, nvs.data(), hvs.data(), keep.data());
      w.stats_.candidate_tests += limit;
      next = chunk + limit;
      for (std::size_t k = 0; k < kept; ++k) {
        const std::size_t i = chunk + keep[k];
        if ((best_j >= 0 && w.cand_lower_[i] > next_exit_test) || w.cand_depth_[i] >= BoundedDouble::kUnsafe) {
          next = i;  // step 1b goes on from here
          stopped = true;
          break;
        }
        const std::uint32_t id = w.cand_id_[i];
        const double height_mag = w.cand_height_mag_[i], norm = w.cand_norm_[i];
        const double nv = nvs[keep[k]], hv = hvs[keep[k]];
        // A pivot point has n(c) = 0 exactly, so a certain sign excludes it; only the
        // uncertain branch has to skip the pivot explicitly.
        const double n_bound = n_mag * norm;
        const double en = n_bound * n_eps;
        bool n_certain = is_certifiable(n_bound);
        if (n_certain && nv < -en) continue;
        if (!n_certain || !(nv > en)) {
          if (is_pivot(id) || spatial_side(&w.cand_q_[i * d], id) != sigma) continue;  // decided exactly
          n_certain = false;
        }
        const double h_bound = h_mag_d * height_mag + h_mag * norm;
        double lo = 0, hi = kInf;
        if (is_certifiable(h_bound) && (n_certain || nv + en > 0)) {
          const double eh = h_bound * relative_error(h_depth_base + w.cand_depth_[i]);
          const double lo_den = nv + en;  // > 0
          // As in pencil_filter: lo > u_best without a division (the 1e-15 covers
          // the product's rounding; u_best = inf never rejects).
          const double lo_num = std::max(0.0, hv - eh) * (1 - 1e-12);
          if (lo_num > u_best * lo_den * (1 + 1e-15)) continue;
          lo = lo_num / lo_den;
          if (n_certain) hi = (hv + eh) / (nv - en) * (1 + 1e-12);
        }
        if (lo > u_best) continue;
        w.contenders_.push_back({static_cast<std::uint32_t>(i), lo});
        if (hi < u_best) {
          u_best = hi;
          best_j = static_cast<std::int64_t>(i);
          // (2r)^2 of the plane through this candidate, estimated from lambda_c.
          const double lambda = hv / nv;
          double slope2 = 0;
          for (int c = 0; c < d; ++c) slope2 += (h[c] - lambda * nn[c]) * (h[c] - lambda * nn[c]);
          next_exit_test = w.exit_estimate(slope2 / (h[d] * h[d]));
        }
      }
    }
    // The exact winner among the contenders still in reach of the best bracket
    // (planes about one pivot are ordered, so one pass keeps the lowest).
    if (!w.contenders_.empty()) {
      const std::uint32_t first = best_j >= 0 ? static_cast<std::uint32_t>(best_j) : w.contenders_.front().index;
      take_candidate(first);
      for (const Contender& k : w.contenders_) {
        if (k.index == first || k.lower > u_best) continue;
        if (lifted_side(&w.cand_q_[k.index * d], candidate_lift(k.index), w.cand_id_[k.index]) < 0) {
          take_candidate(k.index);
        }
      }
    }
  }

  // 1b. The certified scan: certifies the pencil scan's exit, then scans what remains
  //     of the cached candidates (all of them when the pencil scan could not run),
  //     nearest first, rebuilding the plane at each improvement; stops once the best
  //     sphere is certified to lie within the distance scanned. True when the
  //     candidates decide the wrap (no tree query needed).
  bool certified_scan() {
    const std::size_t count = w.cand_id_.size();
    for (; next < count; ++next) {
      if (best_id >= 0 && w.cand_lower_[next] > next_exit_test) {
        if (certified_beyond(w.cand_lower_[next])) return true;
        next_exit_test = w.cand_lower_[next] * (1 + 1e-6);
      }
      const std::uint32_t id = w.cand_id_[next];
      if (is_pivot(id)) continue;
      ++w.stats_.candidate_tests;
      const double* q = &w.cand_q_[next * d];
      if (spatial_side(q, id) != sigma) continue;
      if (best_id < 0 || lifted_side(q, candidate_lift(next), id) < 0) take_candidate(next);
    }
    if (best_id >= 0 && certified_beyond(w.r2_certified_)) return true;
    return w.r2_certified_ == kInf;  // every point was scanned
  }

  // 2. No eligible candidate: any point of the tree strictly on side sigma. False
  //    when there is none (the facet is on the hull: the Voronoi edge is unbounded).
  bool hull_query() {
    ++w.stats_.hull_queries;
    const std::optional<std::uint32_t> beyond =
        w.tree_.any_beyond(x, normal.data(), sigma, [&](std::uint32_t p, const double* pp) {
          if (p == w.x_ || is_pivot(p)) return 0;  // on the hyperplane
          std::array<double, kMaxDimension> q;
          w.relative(p, pp, q.data());
          return spatial_side(q.data(), p);
        });
    if (!beyond) return false;
    take_point(*beyond);
    return true;
  }

  // 3. Any point below the plane is hit before the best: take it and ask again. The
  //    lowered plane stays above everything already rejected (the planes about a
  //    fixed pivot form a pencil), so this terminates with the first hit.
  void sphere_queries() {
    for (;;) {
      ++w.stats_.sphere_queries;
      const std::optional<std::uint32_t> below = first_point_below();
      if (!below) return;
      ++w.missed_candidates_;
      take_point(*below);
    }
  }

  bool has_best() const { return best_id >= 0; }

  // The wrap's answer; writes the hit's plane, oriented so that every point is on or
  // above it (the next wraps' reference).
  WrapResult result(BoundedDouble* hit_plane) {
    if (best_id < 0) return WrapResult::unbounded();
#ifdef SPOKEMESH_CHECK_INVARIANTS
    {
      const auto hit = static_cast<std::uint32_t>(best_id);
      SPOKEMESH_INVARIANT(hit != w.x_ && !is_pivot(hit), "a wrap hits a point outside its pivot");
      std::array<double, kMaxDimension> q;
      w.relative(hit, w.ps_.point(hit), q.data());
      SPOKEMESH_INVARIANT(spatial_side(q.data(), hit) == sigma, "a wrap hits a point on the side it turns to");
    }
#endif
    for (int c = 0; c < cols; ++c) hit_plane[c] = sigma > 0 ? plane[c] : -plane[c];
    return WrapResult::hit(static_cast<std::uint32_t>(best_id));
  }

 private:
  // Side of the pivot's spatial hyperplane q = p - x lies on (0: on it).
  int spatial_side(const double* q, std::uint32_t id) {
    double v = 0, a = 0;
    for (int c = 0; c < d; ++c) {
      v += normal[c].value * q[c];
      a += normal[c].magnitude * std::fabs(q[c]);
    }
    const int s = certified(v, a, normal_depth + d + 3);
    if (s != BoundedDouble::kUnknownSign) return s;
    // Exactly on the hyperplane without the exact stage: every term is zero because
    // its normal component is exactly zero (no monomial survives: magnitude 0 at a
    // safe depth) or the point shares x's coordinate (fl(p - x) == 0 iff p == x).
    // Grids meet this all the time: pivots on an axis-aligned face give an
    // axis-aligned normal, and the face's other points lie on it.
    if (a == 0 && normal_depth < BoundedDouble::kUnsafe) {
      bool zero = true;
      for (int c = 0; c < d; ++c) zero &= normal[c].magnitude == 0 || q[c] == 0;
      if (zero) return 0;
    }
    ++w.stats_.exact_fallbacks;
    rows[d - 1] = Row::of_point(id);
    return w.predicates_.spatial_sign_exact(w.x_, std::span<const Row>(rows.data(), d));
  }

  bool is_pivot(std::uint32_t id) const {
    for (int r = 0; r < d - 1; ++r) {
      if (pivot[r].point == id) return true;
    }
    return false;
  }

  // The best point so far and its plane: the cofactors of the query row of
  // det[pivot; b; query], i.e. the plane through the lifted pivot, x and b.
  void take(std::uint32_t id, const BoundedDouble* b) {
    best_id = id;
    plane_depth = 0;
    for (int c = 0; c < cols; ++c) {
      // M_c = det[pivot; b] without column c, expanded along b's row.
      BoundedDouble m{};
      int t = 0;
      for (int c2 = 0; c2 < cols; ++c2) {
        if (c2 == c) continue;
        const BoundedDouble term = b[c2] * w.minors_[all ^ (1u << c) ^ (1u << c2)];
        const bool plus = ((d - 1 + t) % 2 == 0);
        m = (t == 0) ? (plus ? term : -term) : (plus ? m + term : m - term);
        ++t;
      }
      plane[c] = ((d + c) % 2 == 0) ? m : -m;
      plane_depth = std::max(plane_depth, plane[c].depth);
    }
    double s = 0;
    for (int c = 0; c < d; ++c) s += plane[c].value * plane[c].value;
    next_exit_test = w.exit_estimate(s / (plane[d].value * plane[d].value));  // |slope|^2 = (2r)^2 unweighted
  }
  Lift candidate_lift(std::size_t j) const { return {0, w.cand_height_[j], w.cand_height_mag_[j], w.cand_depth_[j]}; }
  void take_candidate(std::size_t j) {
    std::array<BoundedDouble, kMaxCols> b;
    w.lifted_row(&w.cand_q_[j * d], candidate_lift(j), b.data());
    take(w.cand_id_[j], b.data());
  }
  void take_point(std::uint32_t id) {
    std::array<BoundedDouble, kMaxCols> b;
    approx_row(w.ps_, w.x_, Row::of_point(id), cols, b.data(), w.extras_);
    take(id, b.data());
  }

  // Side of the lifted point (q, height) relative to the best plane: > 0 above, < 0
  // below (the plane's "up" cofactor plane[d] has the sign sigma).
  int lifted_side(const double* q, const Lift& lift, std::uint32_t id) {
    double v = plane[d].value * lift.height, a = plane[d].magnitude * lift.magnitude;
    for (int c = 0; c < d; ++c) {
      v += plane[c].value * q[c];
      a += plane[c].magnitude * std::fabs(q[c]);
    }
    const int depth = lift.depth >= BoundedDouble::kUnsafe ? BoundedDouble::kUnsafe : plane_depth + lift.depth + d + 4;
    int s = certified(v, a, depth);
    if (s == BoundedDouble::kUnknownSign || s == 0) {
      ++w.stats_.exact_fallbacks;
      rows[d - 1] = Row::of_point(static_cast<std::uint32_t>(best_id));
      rows[d] = Row::of_point(id);
      s = w.predicates_.lifted_sign_exact(w.x_, std::span<const Row>(rows.data(), cols), true);
    }
    return s * sigma;
  }

  // Certifies that every point with exact |q|^2 >= bound is strictly above the best
  // plane: above holds where |q| > |slope| (the plane is h = slope . q through x).
  // With weights, height >= |q|^2 - e (e = weight_excess_), and |q| > |slope| + sqrt(e)
  // gives |q|^2 - e > |slope| |q| (as |q| > sqrt(e)): the bound shrinks to
  // (sqrt(bound) - sqrt(e))^2, rounded down.
  bool certified_beyond(double bound) const {
    if (bound == kInf) return true;
    if (w.weight_excess_ > 0) {
      const double reach = std::sqrt(bound) * (1 - 1e-12) - std::sqrt(w.weight_excess_) * (1 + 1e-12);
      if (!(reach > 0)) return false;
      bound = reach * reach * (1 - 1e-12);
    }
    BoundedDouble e = BoundedDouble::exact(bound) * plane[d] * plane[d];
    for (int c = 0; c < d; ++c) e = e - plane[c] * plane[c];
    return e.certified_sign() == 1;
  }

  // A point of the tree strictly below the best plane (inside its sphere), not among
  // the scanned candidates, if any.
  std::optional<std::uint32_t> first_point_below() {
    // The points below the plane are those inside its sphere: with O = sigma * plane
    // (O_d > 0), centre m = -O / (2 O_d) relative to x and radius |m| (with weights,
    // p is below when |q - m|^2 < |m|^2 + w_p - w_x, so the radius grows to
    // sqrt(|m|^2 + weight_excess_)). Boxes are
    // pruned by their distance from the computed centre, against a radius enlarged
    // by delta, a certified bound on |computed centre - true centre|: with
    // |O_c - true| <= e_c, |O_d - true| <= e_d and A = O_d - e_d > 0,
    // |dm_c| <= (e_c / A + |O_c| e_d / (A O_d)) / 2, plus the roundings of m and x + m.
    std::array<double, kMaxDimension> centre{};  // absolute coordinates
    double r2_outer = kInf;                      // prune beyond this; kInf: no pruning
    const double o_d = std::fabs(plane[d].value);
    const double e_d = filter::error_bound(plane[d].magnitude, plane[d].depth);
    const double A = o_d - e_d;
    if (A > 0 && plane_depth < BoundedDouble::kUnsafe) {
      double m2 = 0, delta = 0, c_max = 0;
      for (int c = 0; c < d; ++c) {
        const double o_c = sigma * plane[c].value;
        const double e_c = filter::error_bound(plane[c].magnitude, plane[c].depth);
        const double m = -o_c / (2 * o_d);
        m2 += m * m;
        delta +=
            (e_c / A + std::fabs(o_c) * e_d / (A * o_d)) * 0.5 * (1 + 1e-9) + std::fabs(m) * 4 * filter::kUnitRoundoff;
        centre[c] = x[c] + m;
        c_max = std::max(c_max, std::fabs(centre[c]));
      }
      delta += c_max * 2 * filter::kUnitRoundoff * d;
      const double r = std::sqrt(m2 + w.weight_excess_) * (1 + 1e-12) + 2 * delta;
      if (r * r <= DBL_MAX / 2) r2_outer = r * r * (1 + 1e-9);
    }
    const double r2_certified = w.r2_certified_;
    auto may_contain = [&](const float* lo, const float* hi) {
      // Boxes inside the certified ball hold only scanned candidates, all above the
      // plane already (pencil argument above).
      double far2 = 0, near2 = 0;
      for (int c = 0; c < d; ++c) {
        const double reach = std::max(std::fabs(lo[c] - x[c]), std::fabs(hi[c] - x[c]));
        far2 += reach * reach;
        const double gap = std::max({lo[c] - centre[c], 0.0, centre[c] - hi[c]});
        near2 += gap * gap;
      }
      return far2 * (1 + 1e-9) >= r2_certified && (r2_outer == kInf || near2 <= r2_outer);
    };
    return w.tree_.find_first(may_contain, [&](std::uint32_t p, const double* pp) {
      if (p == w.x_ || p == best_id || is_pivot(p)) return false;
      if (r2_outer != kInf && p < w.image_first_) {
        // A point is a box of its own: outside the enlarged sphere, certainly above.
        // (An image's stored coordinates are not its position: it goes to the test.)
        double near2 = 0;
        for (int c = 0; c < d; ++c) near2 += (pp[c] - centre[c]) * (pp[c] - centre[c]);
        if (near2 > r2_outer) return false;
      }
      std::array<double, kMaxDimension> q;
      const Lift lift = w.relative_row(p, pp, q.data());
      if (lift.norm2 * (1 + 1e-9) < r2_certified) return false;  // a scanned candidate
      return lifted_side(q.data(), lift, p) < 0;
    });
  }

  StarWalker& w;
  const Row* pivot;  // d - 1 rows
  const double* x;   // the seed's coordinates
  std::array<BoundedDouble, kMaxDimension> normal;
  int normal_depth = 0;
  std::array<Row, kMaxCols> rows;  // scratch for the exact stage: the pivot, then two more
  int sigma = 0;                   // the side turned to
  // The best point so far (-1: none) and its lifted plane through the pivot and x.
  std::int64_t best_id = -1;
  std::array<BoundedDouble, kMaxCols> plane;
  int plane_depth = 0;
  double next_exit_test = kInf;  // estimated (2r)^2 of the best sphere: where scanning may stop
  std::size_t next = 0;          // the next candidate the certified scan (1b) looks at
};

// A wrap is the steps of WrapState in order: the candidates decide it unless the
// sphere of the best point reaches beyond them (or none was eligible), when the k-d
// tree finishes it.
template <int D>
StarWalker::WrapResult StarWalker::wrap_kernel(const Row* pivot, Side side, const BoundedDouble* reference,
                                               BoundedDouble* hit_plane) {
  static_assert(D >= 2 && D <= kMaxDimension);
  ++stats_.wraps;
  WrapState<D> wrap(*this, pivot);
  wrap.pivot_minors();
  wrap.orient(side);
  if (options_.cancel != nullptr && options_.cancel->load(std::memory_order_relaxed)) return WrapResult::cancelled();
  if (past_deadline()) return WrapResult::cancelled();
  wrap.pencil_scan(reference);
  if (!wrap.certified_scan()) {
    if (!wrap.has_best() && !wrap.hull_query()) return WrapResult::unbounded();
    wrap.sphere_queries();
  }
  return wrap.result(hit_plane);
}

Status StarWalker::stopped() const {
  if (options_.cancel != nullptr && options_.cancel->load(std::memory_order_relaxed)) {
    return cancelled("star computation cancelled");
  }
  if (past_deadline()) {
    return deadline_exceeded("star computation past its deadline");
  }
  return cancelled("star computation cancelled");
}

Status StarWalker::first_simplex(std::uint32_t* found, BoundedDouble* plane, bool& hidden) {
  const int d = d_;
  hidden = false;
  // Level 0's reference is the plane tangent to the paraboloid at x (h = 0), which
  // holds every direction row; each later level's is the previous level's hit. With
  // weights, a plane h = slope . q through lifted x below every other lifted point
  // (power_start), whose direction rows are lifted onto it.
  if (extras_.weights != nullptr) {
    bool started = false;
    if (Status s = power_start(hidden, found, started); !s.is_ok() || hidden) return s;
    if (started) {  // a cell of no volume: the star's first simplex found directly
      ensure_candidates();
      simplex_plane(found, plane);
      return Status::ok();
    }
  }
  ensure_candidates();  // after the start: a hidden seed needs none
  std::array<BoundedDouble, kMaxCols> reference;
  for (int c = 0; c < d; ++c) reference[c] = BoundedDouble::exact(-slope_[c]);
  reference[d] = BoundedDouble::exact(1.0);
  std::uint64_t state = detail::seed_state(options_.random_seed, x_);
  std::array<Row, kMaxCols> rows;
  for (int attempt = 0;; ++attempt) {
    for (double& w : directions_) w = random_unit(state);
    for (int r = 0; r < d; ++r) rows[r] = Row::of_direction(&directions_[r * d]);
    if (predicates_.spatial_sign(x_, std::span<const Row>(rows.data(), d)) != 0) break;
    if (attempt > 100) return internal_error("could not draw independent spoke directions");
  }
  for (int k = 0; k < d; ++k) {
    // Pivot: the points found so far and all but one of the remaining directions.
    int r = 0;
    for (int i = 0; i < k; ++i) rows[r++] = Row::of_point(found[i]);
    for (int i = 0; i < d - 1 - k; ++i) rows[r++] = Row::of_direction(&directions_[i * d]);
    const double* spoke = &directions_[(d - 1 - k) * d];  // the side the spoke goes to
    WrapResult hit = wrap(rows.data(), Side{.toward = spoke}, reference.data(), plane);
    if (hit.kind == WrapResult::Kind::kUnbounded) {
      hit = wrap(rows.data(), Side{.toward = spoke, .reverse = true}, reference.data(), plane);
    }
    if (hit.kind == WrapResult::Kind::kCancelled) return stopped();
    if (!hit.is_hit()) return internal_error("no lifted point on either side of a spoke pivot (degenerate input?)");
    found[k] = hit.point;
    std::copy(plane, plane + d + 1, reference.begin());
  }
  return Status::ok();
}

void StarWalker::ensure_candidates() {
  if (loaded_) return;
  load_candidates(cand_k_);
  loaded_ = true;
}

void StarWalker::prepare_wrap() {
  ensure_candidates();
  if (missed_candidates_ >= kGrowAfterMisses && !grown_ && cand_id_.size() + 1 < ps_.size()) {
    // The tree keeps finding points the candidates lack: typical of seeds near the
    // hull, whose Delaunay spheres are large. A larger neighbourhood is cheaper than a
    // tree query per remaining wrap.
    cand_k_ *= 2;
    load_candidates(cand_k_);
    grown_ = true;
  }
}

void StarWalker::simplex_plane(const std::uint32_t* ids, BoundedDouble* out) {
  (this->*kernels_.simplex_plane)(ids, out);
}

template <int D>
void StarWalker::simplex_plane_kernel(const std::uint32_t* ids, BoundedDouble* out) {
  // The cofactors of the query row of det[ids; query], as plane_through in the wrap.
  constexpr int cols = D + 1;
  constexpr unsigned all = (1u << cols) - 1u;
  std::array<BoundedDouble, D * cols> rows;
  for (int r = 0; r < D; ++r) approx_row(ps_, x_, Row::of_point(ids[r]), cols, &rows[r * cols], extras_);
  minors_table_fixed<D, cols>(rows.data(), minors_.data());
  for (int c = 0; c < cols; ++c) {
    const BoundedDouble& m = minors_[all ^ (1u << c)];
    out[c] = ((D + c) % 2 == 0) ? m : -m;
  }
}

void StarWalker::prefetch(std::uint32_t seed) const {
  if (seed >= ps_.size()) return;
  __builtin_prefetch(ps_.point(seed));
  if (options_.edges != nullptr) options_.edges->prefetch(seed);
  if (options_.facets != nullptr) options_.facets->prefetch_start(seed);
}

// The walk of one star for d >= 3 (StarWalker::compute): its state and its steps, in
// the order run() takes them. A start (a facet of x's star from the memo, or recursive
// spokes), then the queue of simplices found: each open facet the memo answers is taken
// at once, one it cannot answer is deferred, and deferred facets are wrapped only when
// the queue has run dry and they are still open. The state is the walker's per-seed
// arrays (work_ and the parallel arrays beside it), kept there between seeds so that
// nothing is allocated once warm; this class names what each step does with them.
class StarWalker::StarWalk {
 public:
  explicit StarWalk(StarWalker& walker)
      : w(walker), d(walker.d_), sd(static_cast<std::size_t>(walker.d_)), memo(walker.options_.facets) {}

  Status run(StarPart part, Star& out) {
    reset();
    if (Status s = begin(); !s.is_ok()) return s;
    w.deferred_.clear();
    std::size_t next_deferred = 0;
    for (std::size_t i = 0;;) {
      if (i * sd < w.work_.size()) {  // the queue first: memo answers, or defer
        take_answers(i++);
        continue;
      }
      while (next_deferred < w.deferred_.size() && !is_open(w.deferred_[next_deferred])) ++next_deferred;
      if (next_deferred == w.deferred_.size()) break;  // every facet walked or closed
      if (Status s = wrap_deferred(w.deferred_[next_deferred++]); !s.is_ok()) return s;
    }
    check_complete();
    w.emit_canonical(hull, part, out);
    out.hidden = hidden;
    return Status::ok();
  }

 private:
  // The walker's per-seed arrays, emptied (their capacity kept).
  void reset() {
    w.work_.clear();
    w.work_planes_.clear();
    w.plane_known_.clear();
    w.work_hashes_.clear();
    w.work_facets_.clear();
    w.facet_open_.clear();
    w.facet_apex_.clear();
    w.simplex_seen_.reset(d);
    w.facet_seen_.reset(d - 1);
  }

  // Facet `at` (simplex at / d, without its vertex at % d) still has a side to walk.
  bool is_open(std::size_t at) const { return w.facet_open_[w.work_facets_[at]] != 0; }

  // The memo's key of a facet of x's star: x and the d - 1 other vertices (ascending),
  // as the whole facet, ascending.
  void whole_facet(const std::uint32_t* others, std::uint32_t* facet) const {
    int r = 0, i = 0;
    for (; i < d - 1 && others[i] < w.x_; ++i) facet[r++] = others[i];
    facet[r++] = w.x_;
    for (; i < d - 1; ++i) facet[r++] = others[i];
  }
  // The d - 1 ids of a sorted simplex (d ids) without its k-th: still ascending.
  void drop(const std::uint32_t* ids, int k, std::uint32_t* others) const {
    std::copy(ids, ids + k, others);
    std::copy(ids + k + 1, ids + d, others + k);
  }

  // With a memo: records the two apexes a and b across the facet x + others (hash: its
  // memo hash; b may be kHull), if another vertex of it may still come.
  void record(const std::uint32_t* others, std::uint64_t hash, std::uint32_t a, std::uint32_t b) {
    std::array<std::uint32_t, kMaxCols> whole;
    whole_facet(others, whole.data());
    if (!memo->wanted(w.x_, whole.data())) return;
    if (w.cache_credit_ == 0) w.cache_credit_ = memo->reserve(kCacheBatch);
    if (w.cache_credit_ == 0) return;
    --w.cache_credit_;
    memo->insert(w.x_, whole.data(), hash, a, b);
  }

  // Adds a simplex (d ids without x) to the star unless known; its plane if given.
  // Its d facets through x are registered: a facet met for the second time has both
  // of its simplices known, so it needs no wrap (in a triangulation a facet lies in at
  // most two simplices). Walking only the facets still open visits the star's
  // simplices along a spanning tree of their adjacency: m - 1 wraps or lookups for m
  // simplices, where walking every facet once took m d / 2 (3-d: a third fewer, 6-d:
  // two thirds).
  void add_simplex(const std::uint32_t* ids, const BoundedDouble* with_plane) {
    std::array<std::uint32_t, kMaxCols> sorted;
    std::copy(ids, ids + d, sorted.begin());
    detail::sort_small(sorted.data(), d);
    if (!w.simplex_seen_.insert(sorted.data())) return;
    // Its walk will read these points' coordinates, scattered in input order: start
    // the loads now so they overlap the work queued before it.
    for (int k = 0; k < d; ++k) __builtin_prefetch(w.ps_.point(sorted[k]));
    w.work_.insert(w.work_.end(), sorted.begin(), sorted.begin() + d);
    if (with_plane != nullptr) {
      w.work_planes_.insert(w.work_planes_.end(), with_plane, with_plane + d + 1);
    } else {
      w.work_planes_.resize(w.work_planes_.size() + sd + 1);
    }
    w.plane_known_.push_back(with_plane != nullptr ? 1 : 0);
    const std::size_t hashes_at = w.work_hashes_.size();
    if (memo != nullptr) {
      // Its facets' hashes (facet k: without sorted[k], x included), for the prefetch
      // below and the lookups.
      w.work_hashes_.resize(hashes_at + sd);
      memo->facet_hashes(w.x_, sorted.data(), &w.work_hashes_[hashes_at]);
    }
    for (int k = 0; k < d; ++k) {
      std::array<std::uint32_t, kMaxCols> others;
      drop(sorted.data(), k, others.data());
      bool first = false;
      const std::uint32_t at = w.facet_seen_.position(others.data(), w.facet_seen_.hash(others.data()), first);
      if (first) {
        w.facet_open_.push_back(1);
        w.facet_apex_.push_back(sorted[k]);
      } else if (w.facet_open_[at] != 0) {
        // Closed without a wrap: its answer is known, so record it for the facet's
        // other vertices as a walked wrap would have.
        w.facet_open_[at] = 0;
        if (memo != nullptr) {
          record(others.data(), w.work_hashes_[hashes_at + static_cast<std::size_t>(k)], w.facet_apex_[at], sorted[k]);
        }
      }
      w.work_facets_.push_back(at);
    }
  }

  // The memo's entries for a queued simplex's facets are loads at random: they start
  // kCacheLookahead simplices before the walk reaches it, so the misses are over by
  // then. (Loading them when the simplex is queued is too early in 5-d and 6-d, where
  // thousands wait: the lines were evicted before use.)
  void prefetch_ahead(std::size_t i) {
    constexpr std::size_t kCacheLookahead = 4;
    if (memo == nullptr) return;
    const std::size_t queued = w.work_.size() / sd;
    for (; prefetched < queued && prefetched <= i + kCacheLookahead; ++prefetched) {
      for (std::size_t k = 0; k < sd; ++k) {
        const std::size_t at = prefetched * sd + k;
        if (!is_open(at)) continue;  // both sides known by now
        memo->prefetch(w.work_hashes_[at]);
        if (w.work_[at] > w.x_) memo->prefetch_start(w.work_[at]);  // inserts set later vertices' starts
      }
    }
  }

  // The first simplices: a facet of x's star that an earlier star recorded (its two
  // simplices, or one on the hull), or one simplex by recursive spokes.
  Status begin() {
    std::uint32_t apex_a = 0, apex_b = 0;
    std::array<std::uint32_t, kMaxCols> facet{}, key{};
    if (memo != nullptr && memo->start(w.x_, facet.data(), apex_a, apex_b)) {
      ++w.stats_.cached_starts;
      int r = 0;
      for (int i = 0; i < d; ++i) {
        if (facet[i] != w.x_) key[r++] = facet[i];
      }
      key[d - 1] = apex_a;
      add_simplex(key.data(), nullptr);
      // The start facet is answered (by the memo, so not recorded again): closed.
      bool first = false;
      w.facet_open_[w.facet_seen_.position(key.data(), w.facet_seen_.hash(key.data()), first)] = 0;
      if (apex_b == FacetMemo::kHull) {
        ++hull;
      } else {
        key[d - 1] = apex_b;
        add_simplex(key.data(), nullptr);
      }
      return Status::ok();
    }
    std::array<std::uint32_t, kMaxCols> simplex{};
    std::array<BoundedDouble, kMaxCols> plane;  // every point on or above it
    if (Status s = w.first_simplex(simplex.data(), plane.data(), hidden); !s.is_ok() || hidden) return s;
    add_simplex(simplex.data(), plane.data());
    return Status::ok();
  }

  // Queued simplex i: each open facet the memo answers is closed at once (its far
  // simplex queued, or counted on the hull); the others are deferred to a wrap. Taking
  // every memo answer first lets them close facets a breadth-first walk would have
  // wrapped (2-d: the far side of a ring often closes by itself).
  void take_answers(std::size_t i) {
    prefetch_ahead(i);
    std::array<std::uint32_t, kMaxCols> simplex, others, whole;
    std::copy(w.work_.begin() + static_cast<std::ptrdiff_t>(i * sd),
              w.work_.begin() + static_cast<std::ptrdiff_t>(i * sd + sd), simplex.begin());
    for (int k = 0; k < d; ++k) {  // facet k drops simplex[k]
      const std::size_t at = i * sd + static_cast<std::size_t>(k);
      if (!is_open(at)) continue;  // both sides known, or walked from the other side
      std::uint32_t across = 0;
      if (memo != nullptr) {
        drop(simplex.data(), k, others.data());
        whole_facet(others.data(), whole.data());
        if (memo->lookup(w.x_, whole.data(), w.work_hashes_[at], simplex[k], across)) {
          ++w.stats_.cached_wraps;
          w.facet_open_[w.work_facets_[at]] = 0;
          if (across == FacetMemo::kHull) {
            ++hull;
          } else {
            others[d - 1] = across;
            add_simplex(others.data(), nullptr);
          }
          continue;
        }
      }
      w.deferred_.push_back(static_cast<std::uint32_t>(at));
    }
  }

  // Wraps deferred facet `at` away from its apex: the simplex beyond it is queued, or
  // the facet is on the hull; the answer is recorded for the facet's other vertices.
  Status wrap_deferred(std::size_t at) {
    w.facet_open_[w.work_facets_[at]] = 0;
    const std::size_t owner = at / sd;
    const int k = static_cast<int>(at % sd);
    const std::uint32_t* ids = &w.work_[owner * sd];
    const std::uint32_t apex = ids[k];
    std::array<std::uint32_t, kMaxCols> others;
    drop(ids, k, others.data());
    w.prepare_wrap();
    BoundedDouble* reference = &w.work_planes_[owner * (sd + 1)];
    if (w.plane_known_[owner] == 0) {
      w.simplex_plane(ids, reference);
      w.plane_known_[owner] = 1;
    }
    std::array<Row, kMaxCols> pivot;
    for (int j = 0; j < d - 1; ++j) pivot[j] = Row::of_point(others[j]);
    std::array<BoundedDouble, kMaxCols> plane;
    const WrapResult hit = w.wrap(pivot.data(), Side{.away_from = apex}, reference, plane.data());
    if (hit.kind == WrapResult::Kind::kCancelled) return w.stopped();
    if (memo != nullptr) record(others.data(), w.work_hashes_[at], apex, hit.is_hit() ? hit.point : FacetMemo::kHull);
    if (!hit.is_hit()) {
      ++hull;
      return Status::ok();
    }
    others[d - 1] = hit.point;
    add_simplex(others.data(), plane.data());
    return Status::ok();
  }

  // A complete star: every facet through x lies in two of its simplices, or in one
  // when it is on the hull (then counted in `hull`), never in more.
  void check_complete() const {
#ifdef SPOKEMESH_CHECK_INVARIANTS
    std::vector<std::uint32_t> uses(w.facet_open_.size(), 0);
    for (const std::uint32_t at : w.work_facets_) ++uses[at];
    std::size_t once = 0;
    for (const std::uint32_t u : uses) {
      SPOKEMESH_INVARIANT(u == 1 || u == 2, "a facet of a star lies in one or two of its simplices");
      once += u == 1 ? 1 : 0;
    }
    SPOKEMESH_INVARIANT(once == hull, "the facets in one simplex of a star are its hull facets");
#endif
  }

  StarWalker& w;
  const int d;
  const std::size_t sd;
  FacetMemo* const memo;
  std::size_t hull = 0;        // star facets on the hull
  bool hidden = false;         // with weights: x is in no simplex
  std::size_t prefetched = 0;  // simplices of work_ whose memo entries are being loaded
};

Result<bool> StarWalker::hidden(std::uint32_t seed) {
  if (extras_.weights == nullptr) return false;
  if (seed >= ps_.size()) {
    return out_of_range("seed " + std::to_string(seed) + " is out of range (the point set has " +
                        std::to_string(ps_.size()) + " points)");
  }
  begin_seed(seed);
  bool hidden = false, started = false;
  std::array<std::uint32_t, kMaxDimension> found{};
  if (Status s = power_start(hidden, found.data(), started); !s.is_ok()) return s;
  return hidden;
}

void StarWalker::begin_seed(std::uint32_t seed) {
  x_ = seed;
  // Heights are at least |q|^2 minus this (rounded up: the difference's rounding
  // error is below 2^-53 of it).
  weight_excess_ =
      extras_.weights != nullptr ? std::max(0.0, (max_weight_ - extras_.weights[seed]) * (1 + 0x1p-50)) : 0.0;
  // Spoke directions lie in the tangent plane unless power_start tilts it for this seed.
  std::fill(slope_.begin(), slope_.end(), 0.0);
  extras_.slope = nullptr;
  predicates_.set_direction_slope(nullptr);
  cand_k_ = options_.initial_candidates != 0 ? options_.initial_candidates : default_candidates(d_);
  loaded_ = false;
  missed_candidates_ = 0;
  grown_ = false;
}

Status StarWalker::compute(std::uint32_t seed, Star& out, StarPart part) {
  if (seed >= ps_.size()) {
    return out_of_range("seed " + std::to_string(seed) + " is out of range (the point set has " +
                        std::to_string(ps_.size()) + " points)");
  }
  ++stats_.seeds;
  begin_seed(seed);
  out.hidden = false;
  if (ring_walk_) return ring_walk_->compute(out, part);
  return StarWalk(*this).run(part, out);
}

void StarWalker::emit_canonical(std::size_t hull, StarPart part, Star& out) {
  // Canonical form: vertices ascending within a simplex, simplices lexicographic.
  const int d = d_;
  const int w = d + 1;
  std::vector<std::uint32_t>& flat = sort_flat_;
  flat.resize(work_.size() / d * w);
  std::size_t m = 0;
  for (std::size_t i = 0; i * d < work_.size(); ++i) {
    const std::uint32_t* ids = &work_[i * d];
    if (part == StarPart::kOwned && *std::min_element(ids, ids + d) < x_) continue;
    std::uint32_t* s = &flat[m++ * w];
    s[0] = x_;
    std::copy(ids, ids + d, s + 1);
    detail::sort_small(s, w);
  }
  std::vector<std::uint32_t>& order = sort_order_;
  order.resize(m);
  std::iota(order.begin(), order.end(), 0u);
  // kWhole: the simplices the seed does not own (their first vertex is smaller) first,
  // as they come; only the owned suffix is ordered.
  const auto owned_from =
      part == StarPart::kWhole
          ? static_cast<std::size_t>(
                std::stable_partition(order.begin(), order.end(), [&](std::uint32_t a) { return flat[a * w] != x_; }) -
                order.begin())
          : std::size_t{0};
  std::sort(order.begin() + static_cast<std::ptrdiff_t>(owned_from), order.end(),
            [&](std::uint32_t a, std::uint32_t b) {
              return std::lexicographical_compare(&flat[a * w], &flat[a * w] + w, &flat[b * w], &flat[b * w] + w);
            });
  out.seed = x_;
  out.dimension = d;
  out.hull_facets = hull;
  out.simplices.resize(m * w);
  for (std::size_t i = 0; i < m; ++i) std::copy(&flat[order[i] * w], &flat[order[i] * w] + w, &out.simplices[i * w]);
  orient_positively(out, part == StarPart::kWhole ? owned_from : 0);
}

void StarWalker::orient_positively(Star& out, std::size_t first) const {
  // Positive orientation, det[s_1 - s_0, ..., s_d - s_0] > 0, as finite-element codes
  // require: by the exact predicate (a Delaunay simplex is never flat, so the sign is
  // never 0), a negative simplex gets its last two vertices swapped. That keeps s_0,
  // the smallest index and so the simplex's owner, first, and the order of simplices
  // (by their sorted vertex lists) unchanged.
  const int d = d_;
  const Predicates pred(ps_);
  for (std::size_t i = first; i < out.size(); ++i) {
    std::uint32_t* s = &out.simplices[i * static_cast<std::size_t>(d + 1)];
    const int sign = pred.orientation(std::span<const std::uint32_t>(s, static_cast<std::size_t>(d + 1)));
    SPOKEMESH_INVARIANT(sign != 0, "a Delaunay simplex is full-dimensional");
    if (sign < 0) std::swap(s[d - 1], s[d]);
  }
}

std::vector<std::uint32_t> star_neighbors(const Star& star) {
  std::vector<std::uint32_t> out;
  for (std::uint32_t v : star.simplices) {
    if (v != star.seed) out.push_back(v);
  }
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

}  // namespace spokemesh
