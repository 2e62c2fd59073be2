#include "spokemesh/approx.hpp"

#include <Eigen/Dense>
#include <gmpxx.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <queue>
#include <unordered_map>
#include <unordered_set>

#include "mixing.hpp"
#include "simd.hpp"
#include "spokemesh/predicates.hpp"

namespace spokemesh {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
// Candidates per dimension whose dot products with all rays of a vertex come from one
// matrix product (the rest, rarely reached, are computed on the fly).
constexpr std::size_t kDottedPerDimension = 512;

// A standard normal variate from 53-bit uniforms (Box-Muller): random directions
// uniform on the sphere, reproducible on every platform (std distributions are not).
double normal_variate(std::uint64_t& state) {
  const double u1 = (static_cast<double>(detail::splitmix64(state) >> 11) + 0.5) * 0x1p-53;
  const double u2 = static_cast<double>(detail::splitmix64(state) >> 11) * 0x1p-53;
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(6.283185307179586 * u2);
}

double dot(const double* a, const double* b, int d) {
  double s = 0;
  for (int c = 0; c < d; ++c) s += a[c] * b[c];
  return s;
}

// A hash for sorted index tuples (Voronoi vertices are keyed by their equidistant set).
struct TupleHash {
  std::size_t operator()(const std::vector<std::uint32_t>& v) const {
    return static_cast<std::size_t>(detail::hash_indices(v.data(), v.size()));
  }
};

// Candidates per chunk of shoot()'s vectorized prefilter.
constexpr std::size_t kRayChunk = 16;

// shoot()'s prefilter over kRayChunk candidates with precomputed dot products: marks
// (keep[i] = 1) those that may be met before t_best, i.e. e.q > 0 and
// 0 < t = (|q|^2 - 2 y.q) / (2 e.q) < t_best, tested without dividing and with a
// 1e-12 margin, so it keeps every candidate the scalar test (which then decides)
// would accept. Branch-free, V's lanes at a time.
template <class V, class M>
[[gnu::always_inline]] inline void ray_prefilter_lanes(const double* q2, const double* yq, const double* eq,
                                                       double t_best, std::uint8_t* keep) {
  constexpr std::size_t kLanes = sizeof(V) / sizeof(double);
  for (std::size_t i = 0; i < kRayChunk; i += kLanes) {
    V a, b, c;
    std::memcpy(&a, q2 + i, sizeof a);
    std::memcpy(&b, yq + i, sizeof b);
    std::memcpy(&c, eq + i, sizeof c);
    const V num = a - 2 * b, den = 2 * c;
    const M m = (c > 0) & (num > 0) & (num < t_best * den * (1 + 1e-12));
    for (std::size_t k = 0; k < kLanes; ++k) keep[i + k] = m[k] != 0 ? 1 : 0;
  }
}

void ray_prefilter_sse2(const double* q2, const double* yq, const double* eq, double t_best, std::uint8_t* keep) {
  ray_prefilter_lanes<detail::Double2, detail::Mask2>(q2, yq, eq, t_best, keep);
}

SPOKEMESH_TARGET_AVX2 void ray_prefilter_avx2(const double* q2, const double* yq, const double* eq,
                                                         double t_best, std::uint8_t* keep) {
  ray_prefilter_lanes<detail::Double4, detail::Mask4>(q2, yq, eq, t_best, keep);
}

}  // namespace

ApproxWalker::ApproxWalker(const KdTree& tree, ApproxOptions options)
    : tree_(tree), ps_(tree.points()), options_(options), d_(ps_.dimension()) {}

void ApproxWalker::load_candidates() {
  const std::size_t n = ps_.size();
  // Enough neighbours that most rays end inside the list (a point at distance r from
  // x cannot be hit before the ray is r / 2 from x); the rest fall back to a scan.
  const std::size_t k = std::min(n, std::max<std::size_t>(256, 512 * static_cast<std::size_t>(d_)) + 1);
  std::vector<std::uint32_t> ids(k);
  std::vector<double> d2(k);
  const std::size_t got = tree_.knn(ps_.point(x_), k, ids.data(), d2.data());
  cand_id_.clear();
  cand_q_.clear();
  cand_norm2_.clear();
  const double* x = ps_.point(x_);
  for (std::size_t i = 0; i < got; ++i) {
    if (ids[i] == x_) continue;
    const double* p = ps_.point(ids[i]);
    double s = 0;
    for (int c = 0; c < d_; ++c) {
      const double q = p[c] - x[c];
      cand_q_.push_back(q);
      s += q * q;
    }
    cand_id_.push_back(ids[i]);
    cand_norm2_.push_back(s);
  }
  cand_radius2_ = got == n ? kInf : d2[got - 1] * (1 - 2e-9);
}

std::int64_t ApproxWalker::shoot(const double* y, const double* e, const std::uint32_t* exclude, int excluded,
                                 double& t_out, const double* yq, const double* eq_list, std::size_t dotted) {
  ++rays_;
  const int d = d_;
  std::int64_t best = -1;
  // reach2: (2 |z_best|)^2 (z = y + t e); no point farther than 2 |z_best| from x can
  // be hit first.
  double t_best = kInf, reach2 = kInf;
  auto is_excluded = [&](std::uint32_t id) {
    if (id == x_) return true;
    for (int i = 0; i < excluded; ++i) {
      if (exclude[i] == id) return true;
    }
    return false;
  };
  // A point q (relative to x) becomes as close to y + t e as x is when
  // |q|^2 - 2 y.q = 2 t e.q; only points with e.q > 0 are ever reached.
  auto consider_dots = [&](std::uint32_t id, double q2, double yqv, double eqv) {
    if (!(eqv > 0)) return;
    const double t = (q2 - 2 * yqv) / (2 * eqv);
    if (!(t > 0) || t >= t_best || is_excluded(id)) return;
    t_best = t;
    best = id;
    double z2 = 0;
    for (int c = 0; c < d; ++c) {
      const double z = y[c] + t * e[c];
      z2 += z * z;
    }
    reach2 = 4 * z2 * (1 + 2e-9);
  };
  auto consider = [&](std::uint32_t id, const double* q, double q2) {
    consider_dots(id, q2, dot(y, q, d), dot(e, q, d));
  };
  const std::size_t count = cand_id_.size();
  std::size_t j = 0;
  if (yq != nullptr) {
    // Whole chunks through the prefilter; each candidate still goes through the same
    // reach test and, if kept, consider_dots, in order: the same result as without.
    const auto prefilter = detail::has_avx2() ? &ray_prefilter_avx2 : &ray_prefilter_sse2;
    std::array<std::uint8_t, kRayChunk> keep;
    bool reached = false;
    while (!reached && j + kRayChunk <= dotted) {
      prefilter(&cand_norm2_[j], &yq[j], &eq_list[j], t_best, keep.data());
      for (std::size_t i = 0; i < kRayChunk; ++i, ++j) {
        if (!(cand_norm2_[j] <= reach2)) {
          reached = true;
          break;
        }
        if (keep[i] != 0) consider_dots(cand_id_[j], cand_norm2_[j], yq[j], eq_list[j]);
      }
    }
    for (; !reached && j < dotted && cand_norm2_[j] <= reach2; ++j) {
      consider_dots(cand_id_[j], cand_norm2_[j], yq[j], eq_list[j]);
    }
  }
  for (; j < count && cand_norm2_[j] <= reach2; ++j) consider(cand_id_[j], &cand_q_[j * d], cand_norm2_[j]);
  if (j == count && reach2 > cand_radius2_) {
    // The hit (or its absence) is not decided by the list: branch and bound over the
    // k-d tree. A box can hold a point hit before t_best only if
    //   t >= max(0, dist(x + y, box)^2 - |y|^2) / (2 max_{q in box} e . (q - x))
    // is smaller (numerator: |q - y|^2 - |y|^2; denominator: 2 e . (q - x)); only if
    // it reaches beyond the listed radius (listed points were considered); and, once
    // a hit is known, only if it meets the ball through x centred at the hit's end
    // z = y + t_best e: along the ray, |q - z(t)|^2 - |z(t)|^2 is affine in t and not
    // negative at t = 0 (y is on the boundary of x's cell), so a point met before
    // t_best is strictly inside that ball.
    const double* x = ps_.point(x_);
    const double y2 = dot(y, y, d);
    scratch_.resize(static_cast<std::size_t>(d));
    tree_.find_first(
        [&](const float* lo, const float* hi) {
          double dist2 = 0, reach_e = 0, far2 = 0, ball_gap2 = 0, z2 = 0;
          const bool hit = t_best < kInf;
          for (int c = 0; c < d; ++c) {
            const double yc = x[c] + y[c];
            const double gap = yc < lo[c] ? lo[c] - yc : (yc > hi[c] ? yc - hi[c] : 0.0);
            dist2 += gap * gap;
            reach_e += std::max(e[c] * (lo[c] - x[c]), e[c] * (hi[c] - x[c]));
            const double far = std::max(std::fabs(lo[c] - x[c]), std::fabs(hi[c] - x[c]));
            far2 += far * far;
            if (hit) {
              const double z = y[c] + t_best * e[c], zc = x[c] + z;
              const double zgap = zc < lo[c] ? lo[c] - zc : (zc > hi[c] ? zc - hi[c] : 0.0);
              ball_gap2 += zgap * zgap;
              z2 += z * z;
            }
          }
          if (!(reach_e > 0) || far2 * (1 + 1e-9) < cand_radius2_) return false;
          if (hit && ball_gap2 > z2 * (1 + 1e-9)) return false;
          const double lower = std::max(0.0, dist2 - y2) / (2 * reach_e);
          return lower < t_best * (1 + 1e-9);
        },
        [&](std::uint32_t id, const double* p) {  // p: the tree's leaf-ordered copy
          double q2 = 0;
          for (int c = 0; c < d; ++c) {
            scratch_[c] = p[c] - x[c];
            q2 += scratch_[c] * scratch_[c];
          }
          if (q2 >= cand_radius2_) consider(id, scratch_.data(), q2);  // listed points were considered
          return false;  // visit every box that may still improve the hit
        });
  }
  t_out = t_best;
  return best;
}

bool ApproxWalker::certify(std::uint32_t s, const double* w) {
  const int d = d_;
  const double* x = ps_.point(x_);
  const double* sp = ps_.point(s);
  // The witness W* = x + w - (N / D) a, with a = s - x, D = 2|a|^2, N = 2 w.a - |a|^2:
  // the projection of x + w onto the bisector of x and s. For another point q, with
  // q' = q - x, |W* - q|^2 - |W* - x|^2 = G_q / D where
  //   G_q = D |q'|^2 - 2 D (w . q') + 2 N (a . q'),
  // a polynomial in the input doubles and w: its sign is decided by the Approx filter
  // (a proven error bound), else exactly with GMP. D > 0 since s != x.
  std::vector<Approx> a(static_cast<std::size_t>(d));
  Approx a2{0, 0, 0}, wa{0, 0, 0};
  for (int c = 0; c < d; ++c) {
    a[c] = Approx::difference(sp[c], x[c]);
    a2 = a2 + a[c] * a[c];
    wa = wa + Approx::exact(w[c]) * a[c];
  }
  const Approx D = Approx::exact(2) * a2;
  const Approx N = Approx::exact(2) * wa - a2;
  // Candidates: points near the witness (a k-d tree ball query with a margin that
  // covers every rounding in locating it); all others are certainly farther.
  const double alpha = N.v / D.v;
  std::vector<double> centre(static_cast<std::size_t>(d));
  double r2 = 0, xmax = 0;
  for (int c = 0; c < d; ++c) {
    const double ws = w[c] - alpha * a[c].v;
    r2 += ws * ws;
    centre[c] = x[c] + ws;
    xmax = std::max(xmax, std::fabs(x[c]));
  }
  // Margins: relative rounding of the radius, absolute rounding of x + w* (|x|), and
  // of w* itself (|w| + |alpha| |a|, should the projection cancel), all far above the
  // few-ulp errors they cover.
  double w2 = 0;
  for (int c = 0; c < d; ++c) w2 += w[c] * w[c];
  const double slack = 1e-12 * (xmax * std::sqrt(static_cast<double>(d)) + std::sqrt(w2) +
                                std::fabs(alpha) * std::sqrt(std::fabs(a2.v)));
  const double r = std::sqrt(r2) * (1 + 1e-6) + slack + 1e-300;
  thread_local std::vector<std::pair<std::uint32_t, double>> near;
  tree_.within(centre.data(), r * r * (1 + 1e-9), near);
  for (const auto& [q, dist2] : near) {
    if (q == x_ || q == s) continue;
    const double* qp = ps_.point(q);
    Approx q2{0, 0, 0}, wq{0, 0, 0}, aq{0, 0, 0};
    for (int c = 0; c < d; ++c) {
      const Approx qc = Approx::difference(qp[c], x[c]);
      q2 = q2 + qc * qc;
      wq = wq + Approx::exact(w[c]) * qc;
      aq = aq + a[c] * qc;
    }
    const Approx g = D * q2 - Approx::exact(2) * D * wq + Approx::exact(2) * N * aq;
    int sign = g.certified_sign();
    if (sign == Approx::kUnknownSign) {
      mpq_class A2 = 0, WA = 0, Q2 = 0, WQ = 0, AQ = 0;
      std::vector<mpq_class> ac(static_cast<std::size_t>(d));
      for (int c = 0; c < d; ++c) {
        ac[c] = mpq_class(sp[c]) - mpq_class(x[c]);
        const mpq_class qc = mpq_class(qp[c]) - mpq_class(x[c]);
        const mpq_class wc(w[c]);
        A2 += ac[c] * ac[c];
        WA += wc * ac[c];
        Q2 += qc * qc;
        WQ += wc * qc;
        AQ += ac[c] * qc;
      }
      const mpq_class De = 2 * A2, Ne = 2 * WA - A2;
      sign = sgn(De * Q2 - 2 * De * WQ + 2 * Ne * AQ);
    }
    if (sign <= 0) return false;  // q is as close to the witness as x and s (or closer)
  }
  return true;
}

Status ApproxWalker::compute(std::uint32_t seed, ApproxNeighbors& out) {
  if (seed >= ps_.size()) {
    return out_of_range("seed " + std::to_string(seed) + " is out of range (the point set has " +
                        std::to_string(ps_.size()) + " points)");
  }
  x_ = seed;
  rays_ = 0;
  // Every direction is drawn from the seed index and the options: replicas and thread
  // counts agree.
  rng_ = detail::seed_state(options_.random_seed, seed) ^
         (static_cast<std::uint64_t>(options_.mode) << 56) ^ (std::uint64_t{options_.max_misses} << 32);
  out = ApproxNeighbors{};
  out.seed = seed;
  load_candidates();
  Status s = options_.mode == ApproxOptions::Mode::kSpokes ? compute_spokes(out) : compute_rsd(out);
  out.rays = rays_;
  std::sort(out.neighbors.begin(), out.neighbors.end());
  return s;
}

Status ApproxWalker::compute_spokes(ApproxNeighbors& out) {
  const int d = d_;
  std::vector<double> u(static_cast<std::size_t>(d)), y(static_cast<std::size_t>(d), 0.0), w(static_cast<std::size_t>(d));
  std::unordered_set<std::uint32_t> found;
  std::uint64_t misses = 0;
  while (misses < options_.max_misses && out.vertices < options_.max_vertices) {
    if (stop_requested()) return cancelled("neighbour walk cancelled");
    for (double& v : u) v = normal_variate(rng_);
    ++out.vertices;
    double t = 0;
    const std::int64_t p = shoot(y.data(), u.data(), nullptr, 0, t);
    bool fresh = false;
    if (p >= 0 && found.count(static_cast<std::uint32_t>(p)) == 0) {
      // The trimmed spoke's end lies on the Voronoi facet of (x, p): the witness.
      for (int c = 0; c < d; ++c) w[c] = t * u[c];
      if (certify(static_cast<std::uint32_t>(p), w.data())) {
        found.insert(static_cast<std::uint32_t>(p));
        out.neighbors.push_back(static_cast<std::uint32_t>(p));
        fresh = true;
      } else {
        ++out.uncertified;
      }
    }
    misses = fresh ? 0 : misses + 1;
  }
  out.misses = misses;
  return Status::ok();
}

Status ApproxWalker::compute_rsd(ApproxNeighbors& out) {
  using Eigen::MatrixXd;
  using Eigen::VectorXd;
  const int d = d_;
  // 1. Recursive spokes down to a Voronoi vertex (Sec. 3.2): at level k the spoke
  //    lies in the flat equidistant to x and the k points found, i.e. orthogonal to
  //    their offsets (Gram-Schmidt), and starts where the previous spoke ended.
  //    Returns false if no vertex was reached within the attempts.
  std::vector<std::uint32_t> S;
  VectorXd y(d);
  std::unordered_set<std::uint32_t> found;           // certified neighbours
  std::unordered_map<std::uint32_t, int> attempts;  // failed certifications per point
  bool descent_found = false;                       // the last descent certified a new neighbour
  // Certifies s with witness w (relative to x) unless already known or tried too often;
  // true if s is a new certified neighbour.
  auto try_certify = [&](std::uint32_t s, const double* w) {
    if (found.count(s) != 0 || attempts[s] >= 3) return false;
    if (certify(s, w)) {
      found.insert(s);
      out.neighbors.push_back(s);
      return true;
    }
    ++attempts[s];
    ++out.uncertified;
    return false;
  };
  auto descend = [&]() -> bool {
    S.clear();
    y.setZero();
    std::vector<double> basis;  // orthonormal rows spanning the offsets found so far
    VectorXd u(d), q(d);
    const double* x = ps_.point(x_);
    // A level whose spokes keep missing (an unbounded face, or a cell without vertices
    // when the points lie in a subspace) ends the descent after a few tries.
    for (int misses_here = 0; static_cast<int>(S.size()) < d; ++misses_here) {
      if (misses_here >= 8 || stop_requested()) return false;
      for (int c = 0; c < d; ++c) u[c] = normal_variate(rng_);
      for (std::size_t b = 0; b * d < basis.size(); ++b) {
        const Eigen::Map<const VectorXd> row(&basis[b * d], d);
        u -= row.dot(u) * row;
      }
      if (!(u.norm() > 1e-9)) continue;
      u.normalize();
      double t = 0;
      std::int64_t p = shoot(y.data(), u.data(), S.data(), static_cast<int>(S.size()), t);
      if (p < 0) {  // unbounded that way: the face reaches the hull; try the other way
        u = -u;
        p = shoot(y.data(), u.data(), S.data(), static_cast<int>(S.size()), t);
      }
      if (p < 0) continue;
      const double* pp = ps_.point(static_cast<std::size_t>(p));
      for (int c = 0; c < d; ++c) q[c] = pp[c] - x[c];
      for (std::size_t b = 0; b * d < basis.size(); ++b) {
        const Eigen::Map<const VectorXd> row(&basis[b * d], d);
        q -= row.dot(q) * row;
      }
      if (!(q.norm() > 0)) continue;  // dependent offsets (degenerate): another direction
      if (S.empty()) {
        // The first spoke's end is on the facet of (x, p): a witness as in plain Spoke
        // Darts, so RSD never finds less than the spokes it shoots (and still works
        // where the cell has no vertices, e.g. points in a lower-dimensional subspace).
        const VectorXd w1 = t * u;
        descent_found = try_certify(static_cast<std::uint32_t>(p), w1.data()) || descent_found;
      }
      y += t * u;
      S.push_back(static_cast<std::uint32_t>(p));
      q.normalize();
      basis.insert(basis.end(), q.data(), q.data() + d);
      misses_here = -1;  // a new level
    }
    std::sort(S.begin(), S.end());
    return true;
  };
  const bool reached_first = descend();
  if (stop_requested()) return cancelled("neighbour walk cancelled");

  // 2. The walk (Sec. 3.3 and 4.4). Vertices whose equidistant points include points
  //    not yet certified go first (then first come, first served): the budget of
  //    misses is spent where new neighbours are, not on re-walking known ones.
  struct Vertex {
    std::vector<std::uint32_t> S;  // the d points equidistant with x, sorted
    VectorXd v;                    // relative to x
  };
  std::vector<Vertex> vertices;
  using Entry = std::pair<int, std::int64_t>;  // (unfound points, -arrival)
  std::priority_queue<Entry> queue;
  std::unordered_set<std::vector<std::uint32_t>, TupleHash> seen;
  auto unfound = [&](const std::vector<std::uint32_t>& set) {
    int k = 0;
    for (std::uint32_t p : set) k += found.count(p) == 0 ? 1 : 0;
    return k;
  };
  if (reached_first) {
    seen.insert(S);
    vertices.push_back({S, y});
    queue.push({unfound(S), 0});
  }
  MatrixXd B(d, d);
  VectorXd f(d), e(d), w(d);
  std::uint64_t misses = 0;
  bool degenerate = false;  // a vertex whose offsets do not span R^d (points in a subspace)
  const double* x = ps_.point(x_);
  for (;;) {
    if (misses >= options_.max_misses || out.vertices >= options_.max_vertices) break;
    if (stop_requested()) return cancelled("neighbour walk cancelled");
    if (queue.empty()) {
      // Every vertex reachable from the first is walked. With every proposal certified,
      // that is the whole cell: done. Otherwise (no vertex was reachable, as for points
      // in a lower-dimensional subspace, or a proposal failed) new recursive spokes,
      // each certifying the facet its first spoke ends on, until M misses.
      out.exhausted = reached_first;
      if (reached_first && out.uncertified == 0 && !degenerate) break;
      ++out.vertices;
      descent_found = false;
      const bool reached = descend();
      misses = descent_found ? 0 : misses + 1;
      if (reached && seen.insert(S).second) {
        queue.push({unfound(S), -static_cast<std::int64_t>(vertices.size())});
        vertices.push_back({S, y});
      }
      continue;
    }
    Vertex vertex = std::move(vertices[static_cast<std::size_t>(-queue.top().second)]);
    queue.pop();
    ++out.vertices;
    // Edge directions: E = -B^{-1} with rows B_m = s_m - x. Column k is orthogonal to
    // every offset but the k-th and points away from s_k: the Voronoi edge that drops s_k.
    for (int m = 0; m < d; ++m) {
      const double* sp = ps_.point(vertex.S[m]);
      for (int c = 0; c < d; ++c) B(m, c) = sp[c] - x[c];
    }
    Eigen::PartialPivLU<MatrixXd> lu(B);
    const MatrixXd E = -lu.inverse();
    if (!E.allFinite()) {
      degenerate = true;
      continue;
    }
    // Re-solve the vertex from its equidistant set (B v = |s_m - x|^2 / 2) rather than
    // trust the sum of rays that reached it: errors do not accumulate along the walk.
    VectorXd rhs(d);
    for (int m = 0; m < d; ++m) rhs[m] = B.row(m).squaredNorm() / 2;
    vertex.v = lu.solve(rhs);
    if (!vertex.v.allFinite()) {
      degenerate = true;
      continue;
    }
    // Every ray from this vertex starts at v and goes along a combination of E's
    // columns: one matrix product gives all their dot products with the candidates.
    // Only the nearest part of the list: most rays end there (the rest of the list is
    // scanned with dot products on the fly, then the tree).
    const auto listed = static_cast<Eigen::Index>(std::min<std::size_t>(cand_id_.size(), kDottedPerDimension * static_cast<std::size_t>(d)));
    const Eigen::Map<const MatrixXd> Q(cand_q_.data(), d, listed);
    MatrixXd R(d, d + 2);
    R.col(0) = vertex.v;
    R.middleCols(1, d) = E;
    R.col(d + 1) = E.rowwise().sum();
    MatrixXd P(listed, d + 2);  // column-major; noalias: no zero-fill before the product
    P.noalias() = Q.transpose() * R;
    VectorXd certify_dots(listed);
    // Certify the new neighbours of this vertex: for s = S_i, the direction
    // sum_{k != i} E_k keeps x and s equidistant and moves away from the others, into
    // the facet of (x, s); the witness is halfway to the first point met that way.
    bool fresh = false, failed_here = false;
    const VectorXd total = E.rowwise().sum();
    for (int i = 0; i < d; ++i) {
      const std::uint32_t s = vertex.S[i];
      if (found.count(s) != 0 || attempts[s] >= 3) continue;
      f = total - E.col(i);
      certify_dots = P.col(d + 1) - P.col(1 + i);
      double t = 0;
      const std::int64_t hit = shoot(vertex.v.data(), f.data(), &s, 1, t, P.col(0).data(), certify_dots.data(),
                                     static_cast<std::size_t>(listed));
      if (hit < 0) t = 2 * std::max(vertex.v.norm(), 1e-300) / std::max(f.norm(), 1e-300);
      w = vertex.v + (t / 2) * f;
      if (try_certify(s, w.data())) {
        fresh = true;
      } else {
        failed_here = true;
      }
    }
    misses = fresh ? 0 : misses + 1;
    // Walk every Voronoi edge leaving this vertex.
    for (int k = 0; k < d; ++k) {
      e = E.col(k);
      double t = 0;
      const std::int64_t q = shoot(vertex.v.data(), e.data(), vertex.S.data(), d, t, P.col(0).data(),
                                   P.col(1 + k).data(), static_cast<std::size_t>(listed));
      if (q < 0) continue;  // an unbounded Voronoi edge
      std::vector<std::uint32_t> next = vertex.S;
      next[k] = static_cast<std::uint32_t>(q);
      std::sort(next.begin(), next.end());
      if (!seen.insert(next).second) continue;
      queue.push({unfound(next), -static_cast<std::int64_t>(vertices.size())});
      vertices.push_back({std::move(next), vertex.v + t * e});
    }
    // Restarts: when this vertex was a miss and nothing queued promises a new point (or
    // its proposals failed certification, as at the spurious vertices of points in a
    // lower-dimensional subspace), new recursive spokes reach a vertex next to a random
    // facet (as plain spokes would) and the walk continues from there.
    if (!fresh && (queue.empty() || queue.top().first == 0 || failed_here)) {
      descent_found = false;
      const bool reached = descend();
      if (descent_found) misses = 0;
      if (reached && seen.insert(S).second) {
        queue.push({unfound(S), -static_cast<std::int64_t>(vertices.size())});
        vertices.push_back({S, y});
      }
    }
  }
  out.misses = misses;
  return Status::ok();
}

}  // namespace spokemesh
