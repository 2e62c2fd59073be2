#include "spokemesh/approx.hpp"

#include <gmpxx.h>
#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <limits>
#include <unordered_map>
#include <unordered_set>

#include "base/invariant.hpp"
#include "base/mixing.hpp"
#include "spokemesh/predicates.hpp"

namespace spokemesh {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

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

// Nearest candidates a ray tests before its ball query (see shoot()).
constexpr std::size_t kHeadCandidates = 32;

}  // namespace

ApproxWalker::ApproxWalker(const KdTree& tree, ApproxOptions options)
    : tree_(tree), ps_(tree.points()), options_(options), d_(ps_.dimension()) {}

void ApproxWalker::load_candidates(std::size_t k) {
  const std::size_t n = ps_.size();
  k = std::min(n, k + 1);
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

std::optional<std::uint32_t> ApproxWalker::shoot(const double* y, const double* e, const std::uint32_t* exclude,
                                                 int excluded, double& t_out, bool head_only) {
  ++rays_;
  const int d = d_;
  std::optional<std::uint32_t> best;
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
  auto consider = [&](std::uint32_t id, const double* q, double q2) {
    const double eq = dot(e, q, d);
    if (!(eq > 0)) return;
    const double t = (q2 - 2 * dot(y, q, d)) / (2 * eq);
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
  const double* x = ps_.point(x_);
  const std::size_t count = cand_id_.size();
  // 1. The nearest candidates give a first hit at t_best. Along the ray,
  //    |q - z(t)|^2 - |z(t)|^2 is affine in t and not negative at t = 0 (y is on the
  //    boundary of x's cell), so every point met before t_best lies strictly inside the
  //    ball through x centred at z(t_best): one ball query then finds them all. That
  //    ball is far smaller than the one of radius 2 |z| around x that a scan of the
  //    sorted list must cover (in 8-d, 2^8 times by volume).
  const std::size_t head = std::min(count, kHeadCandidates);
  std::size_t j = 0;
  for (; j < head && cand_norm2_[j] <= reach2; ++j) consider(cand_id_[j], &cand_q_[j * d], cand_norm2_[j]);
  if (head_only) {
    t_out = t_best;
    return best;
  }
  if (best) {
    double z2 = 0;
    scratch_.resize(static_cast<std::size_t>(2 * d));
    for (int c = 0; c < d; ++c) {
      const double z = y[c] + t_best * e[c];
      z2 += z * z;
      scratch_[static_cast<std::size_t>(d + c)] = x[c] + z;
    }
    tree_.within(&scratch_[static_cast<std::size_t>(d)], z2 * (1 + 1e-9) + 1e-300, near_);
    for (const auto& [id, dist2] : near_) {
      const double* p = ps_.point(id);
      double q2 = 0;
      for (int c = 0; c < d; ++c) {
        scratch_[static_cast<std::size_t>(c)] = p[c] - x[c];
        q2 += scratch_[static_cast<std::size_t>(c)] * scratch_[static_cast<std::size_t>(c)];
      }
      consider(id, scratch_.data(), q2);
    }
    t_out = t_best;
    return best;
  }
  // 2. No hit among them: the rest of the list, nearest first, then the tree.
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
          return false;                                                // visit every box that may still improve the hit
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
  // a polynomial in the input doubles and w: its sign is decided by the BoundedDouble filter
  // (a proven error bound), else exactly with GMP. D > 0 since s != x.
  std::vector<BoundedDouble> a(static_cast<std::size_t>(d));
  BoundedDouble a2{0, 0, 0}, wa{0, 0, 0};
  for (int c = 0; c < d; ++c) {
    a[c] = BoundedDouble::difference(sp[c], x[c]);
    a2 = a2 + a[c] * a[c];
    wa = wa + BoundedDouble::exact(w[c]) * a[c];
  }
  const BoundedDouble D = BoundedDouble::exact(2) * a2;
  const BoundedDouble N = BoundedDouble::exact(2) * wa - a2;
  // Candidates: points near the witness (a k-d tree ball query with a margin that
  // covers every rounding in locating it); all others are certainly farther.
  const double alpha = N.value / D.value;
  std::vector<double> centre(static_cast<std::size_t>(d));
  double r2 = 0, xmax = 0;
  for (int c = 0; c < d; ++c) {
    const double ws = w[c] - alpha * a[c].value;
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
                                std::fabs(alpha) * std::sqrt(std::fabs(a2.value)));
  const double r = std::sqrt(r2) * (1 + 1e-6) + slack + 1e-300;
  thread_local std::vector<std::pair<std::uint32_t, double>> near;
  tree_.within(centre.data(), r * r * (1 + 1e-9), near);
  for (const auto& [q, dist2] : near) {
    if (q == x_ || q == s) continue;
    const double* qp = ps_.point(q);
    BoundedDouble q2{0, 0, 0}, wq{0, 0, 0}, aq{0, 0, 0};
    for (int c = 0; c < d; ++c) {
      const BoundedDouble qc = BoundedDouble::difference(qp[c], x[c]);
      q2 = q2 + qc * qc;
      wq = wq + BoundedDouble::exact(w[c]) * qc;
      aq = aq + a[c] * qc;
    }
    const BoundedDouble g = D * q2 - BoundedDouble::exact(2) * D * wq + BoundedDouble::exact(2) * N * aq;
    int sign = g.certified_sign();
    if (sign == BoundedDouble::kUnknownSign) {
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
  rng_ = detail::seed_state(options_.random_seed, seed) ^ (static_cast<std::uint64_t>(options_.mode) << 56) ^
         (std::uint64_t{options_.max_misses} << 32);
  out = ApproxNeighbors{};
  out.seed = seed;
  // Enough neighbours that most rays end inside the list (a point at distance r from
  // x cannot be hit before the ray is r / 2 from x); the rest fall back to a scan. The
  // RSD walk lists more when it runs out of targets.
  load_candidates(std::max<std::size_t>(256, 512 * static_cast<std::size_t>(d_)));
  Status s = options_.mode == ApproxOptions::Mode::kSpokes ? compute_spokes(out) : compute_rsd(out);
  out.rays = rays_;
  std::sort(out.neighbors.begin(), out.neighbors.end());
  return s;
}

Status ApproxWalker::compute_spokes(ApproxNeighbors& out) {
  const int d = d_;
  std::vector<double> u(static_cast<std::size_t>(d)), y(static_cast<std::size_t>(d), 0.0),
      w(static_cast<std::size_t>(d));
  std::unordered_set<std::uint32_t> found;
  std::uint64_t misses = 0;
  while (misses < options_.max_misses && out.vertices < options_.max_vertices) {
    if (stop_requested()) return cancelled("neighbour walk cancelled");
    for (double& v : u) v = normal_variate(rng_);
    ++out.vertices;
    double t = 0;
    const std::optional<std::uint32_t> p = shoot(y.data(), u.data(), nullptr, 0, t);
    bool fresh = false;
    if (p && found.count(*p) == 0) {
      // The trimmed spoke's end lies on the Voronoi facet of (x, p): the witness.
      for (int c = 0; c < d; ++c) w[c] = t * u[c];
      if (certify(*p, w.data())) {
        found.insert(*p);
        out.neighbors.push_back(*p);
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

// The RSD walk of one seed (compute_rsd): its state and its named steps.
//
// 1. Recursive spokes down to a Voronoi vertex (Sec. 3.2, descend): at level k the
//    spoke lies in the flat equidistant to x and the k points found, i.e. orthogonal
//    to their offsets (Gram-Schmidt), and starts where the previous spoke ended.
// 2. The walk (Sec. 3.3 and 4.4), directed. A Voronoi vertex v of cell(x) is where x
//    and d points S are equidistant; dropping s_k from S leaves a Voronoi edge, and a
//    ray along it meets the next vertex. Which edges to walk is the walk's choice:
//    here each leg heads for one target, a listed point q not yet found, by the
//    simplex method. g(w) = |w - q|^2 - |w - x|^2 is linear in w and >= 0 on cell(x),
//    and 0 exactly on the facet of (x, q): so (x, q) is a Delaunay edge iff the
//    minimum of g over the cell is 0. From the current vertex the walk takes the edge
//    along which g falls fastest (the steepest edge) to the next vertex, until q is
//    among the equidistant points (found, and certified like every new point met on
//    the way), or no edge lowers g (q is not a neighbour: refuted, in floating point,
//    which can only cost recall). The next target is the point whose bisector is
//    nearest to the current vertex, so consecutive legs stay short and the walk
//    sweeps the cell's surface instead of re-walking known parts of it, as an
//    undirected walk does once most of its neighbours are found. A target is first
//    walked to on a relaxed polytope (relaxed_refutes), and only walked for real if
//    that cannot refute it; if its facet is far, a spoke aimed at it replaces the leg
//    (docs/algorithm.md, section 7). Every vertex reached counts, as in the paper, as
//    a miss when it certifies no new neighbour, and so does a target refuted without
//    a leg; M misses in a row stop the walk.
class ApproxWalker::RsdWalk {
 public:
  RsdWalk(ApproxWalker& walker, ApproxNeighbors& out)
      : walker_(walker),
        out_(out),
        d(walker.d_),
        x(walker.ps_.point(walker.x_)),
        y(d),
        B(d, d),
        E(d, d),
        v(d),
        f(d),
        e(d),
        witness(d),
        rhs(d),
        rE(d, d),
        rv(d),
        re(d),
        r_row(d),
        r_col(d),
        r_p(d),
        r_u(d),
        kept_v(d),
        origin(VectorXd::Zero(d)),
        kept_E(d, d) {}

  Status run() {
    const bool reached_first = descend(nullptr, std::nullopt);
    if (walker_.stop_requested()) return cancelled("neighbour walk cancelled");
    relist({});
    // The first vertex, by recursive spokes (again if the spokes miss, or the vertex
    // is degenerate, as for points in a lower-dimensional subspace: each descent
    // still certifies the facet its first spoke ends on).
    at_vertex = reached_first && visit(S);
    if (reached_first && !at_vertex) misses = 1;
    for (;;) {
      if (budget_spent()) break;
      if (walker_.stop_requested()) return cancelled("neighbour walk cancelled");
      if (!at_vertex) {
        descend_again();
        continue;
      }
      const Eigen::Index target = next_target();
      if (target < 0 || (list_more && walker_.cand_radius2_ != kInf)) {
        // Every listed point is found, given up or refuted: the cell is done as far as
        // the list reaches (the whole cell when every point is listed). Otherwise, or
        // when the list looks too short (list_more), list more and go on.
        if (walker_.cand_radius2_ == kInf) {
          // Complete only if nothing was given up: every point certified or refuted.
          out_.exhausted = given_up == 0;
          break;
        }
        grow_list();
        continue;
      }
      head_for(target);
    }
    out_.misses = misses;
    return Status::ok();
  }

 private:
  using MatrixXd = Eigen::MatrixXd;
  using VectorXd = Eigen::VectorXd;
  static constexpr int kStepsPerTarget = 64;
  // Steps of a relaxed walk (no tree queries: cheap) before it gives up; near a
  // manifold the facets of far targets are often 15 or more steps away.
  static constexpr int kRelaxedSteps = 1024;
  // A relaxed walk that needs this many steps to reach the goal's facet is answered
  // by an aimed spoke instead of a leg (measurements: bench/README.md, tuning history).
  static constexpr int kAimAfterSteps = 8;
  // Refutations in a row before the nearest open point is taken instead (ibid.).
  static constexpr int kRefutedBeforeNearest = 8;
  // A candidate's state: still a target, found or given up, refuted.
  static constexpr std::uint8_t kOpen = 0, kSettled = 1, kRefuted = 2;

  bool budget_spent() const {
    return misses >= walker_.options_.max_misses || out_.vertices >= walker_.options_.max_vertices;
  }
  bool found(std::uint32_t s) const { return found_at.count(s) != 0; }

  // Records s, certified, as a neighbour.
  bool accept(std::uint32_t s) {
    SPOKEMESH_INVARIANT(s != walker_.x_ && !found(s), "a neighbour is the seed's, certified once");
    out_.neighbors.push_back(s);
    const double* sp = walker_.ps_.point(s);
    double q2 = 0;
    for (int c = 0; c < d; ++c) {
      found_q.push_back(sp[c] - x[c]);
      q2 += found_q.back() * found_q.back();
    }
    found_at.emplace(s, static_cast<std::uint32_t>(found_q2.size()));
    found_q2.push_back(q2);
    if (q2 >= outer2 && ++outer_found >= 4 * static_cast<std::size_t>(d)) list_more = true;
    return true;
  }

  // Certifies s with witness w (relative to x) unless already known or tried too
  // often; true if s is a new certified neighbour.
  bool try_certify(std::uint32_t s, const double* w) {
    if (found(s) || attempts[s] >= 3) return false;
    if (walker_.certify(s, w)) return accept(s);
    ++attempts[s];
    ++out_.uncertified;
    return false;
  }

  // Recursive spokes from `start` (relative to x; with `first`, a point already met
  // there) down to a vertex S; false if no vertex was reached within the attempts.
  bool descend(const double* start, std::optional<std::uint32_t> first) {
    S.clear();
    y.setZero();
    std::vector<double> basis;  // orthonormal rows spanning the offsets found so far
    VectorXd u(d), q(d);
    if (first) {
      for (int c = 0; c < d; ++c) y[c] = start[c];
      const double* pp = walker_.ps_.point(*first);
      for (int c = 0; c < d; ++c) q[c] = pp[c] - x[c];
      q.normalize();
      basis.insert(basis.end(), q.data(), q.data() + d);
      S.push_back(*first);
    }
    // A level whose spokes keep missing (an unbounded face, or a cell without vertices
    // when the points lie in a subspace) ends the descent after a few tries.
    for (int misses_here = 0; static_cast<int>(S.size()) < d; ++misses_here) {
      if (misses_here >= 8 || walker_.stop_requested()) return false;
      for (int c = 0; c < d; ++c) u[c] = normal_variate(walker_.rng_);
      for (std::size_t b = 0; b * d < basis.size(); ++b) {
        const Eigen::Map<const VectorXd> row(&basis[b * d], d);
        u -= row.dot(u) * row;
      }
      if (!(u.norm() > 1e-9)) continue;
      u.normalize();
      double t = 0;
      std::optional<std::uint32_t> hit = walker_.shoot(y.data(), u.data(), S.data(), static_cast<int>(S.size()), t);
      if (!hit) {  // unbounded that way: the face reaches the hull; try the other way
        u = -u;
        hit = walker_.shoot(y.data(), u.data(), S.data(), static_cast<int>(S.size()), t);
      }
      if (!hit) continue;
      const std::uint32_t p = *hit;
      const double* pp = walker_.ps_.point(p);
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
        descent_found = try_certify(p, w1.data()) || descent_found;
      }
      y += t * u;
      S.push_back(p);
      q.normalize();
      basis.insert(basis.end(), q.data(), q.data() + d);
      misses_here = -1;  // a new level
    }
    std::sort(S.begin(), S.end());
    // Each level's point had an offset independent of the levels above it.
    SPOKEMESH_INVARIANT(
        std::adjacent_find(S.begin(), S.end()) == S.end() && std::find(S.begin(), S.end(), walker_.x_) == S.end(),
        "a descent ends at d distinct points other than the seed");
    return true;
  }

  // Not at a vertex (the last one was degenerate): a fresh descent, counted as one
  // vertex and a miss unless it certifies something.
  void descend_again() {
    ++out_.vertices;
    descent_found = false;
    const bool reached = descend(nullptr, std::nullopt);
    misses = descent_found ? 0 : misses + 1;
    if (reached) {
      --out_.vertices;  // visit() counts it
      const std::uint64_t kept = misses;
      at_vertex = visit(S);
      misses = std::min(misses, kept);
    }
  }

  // Takes the candidate list as it is now: states from `settled` (id -> state, for
  // points listed before) or from what is found, and everything derived from the list.
  void relist(const std::unordered_map<std::uint32_t, std::uint8_t>& settled) {
    SPOKEMESH_INVARIANT(walker_.cand_id_.size() >= static_cast<std::size_t>(listed),
                        "the candidate list only grows (its earlier states are kept)");
    listed = static_cast<Eigen::Index>(walker_.cand_id_.size());
    state.assign(static_cast<std::size_t>(listed), kOpen);
    for (Eigen::Index j = 0; j < listed; ++j) {
      const std::uint32_t id = walker_.cand_id_[static_cast<std::size_t>(j)];
      const auto it = settled.find(id);
      state[static_cast<std::size_t>(j)] = it != settled.end() ? it->second : (found(id) ? kSettled : kOpen);
    }
    slack.resize(listed);
    inv_norm = Eigen::Map<const VectorXd>(walker_.cand_norm2_.data(), listed).array().rsqrt();
    slack_at = ~std::uint64_t{0};
    first_open = 0;
    // Neighbours found in the outer quarter of the candidate list (by distance from
    // x, from outer2 on) suggest more beyond it: a long cell, as near a manifold or in
    // 12-d. 4 d of them set list_more (measurements: bench/README.md).
    const std::vector<double>& norm2 = walker_.cand_norm2_;
    outer2 = walker_.cand_radius2_ == kInf ? kInf : norm2[3 * norm2.size() / 4];
    outer_found = static_cast<std::size_t>(
        std::count_if(found_q2.begin(), found_q2.end(), [&](double q2) { return q2 >= outer2; }));
    list_more = outer_found >= 4 * static_cast<std::size_t>(d);
  }

  // Lists twice as many candidates, keeping the states of those listed before.
  void grow_list() {
    std::unordered_map<std::uint32_t, std::uint8_t> settled;
    for (Eigen::Index j = 0; j < listed; ++j) {
      settled.emplace(walker_.cand_id_[static_cast<std::size_t>(j)], state[static_cast<std::size_t>(j)]);
    }
    walker_.load_candidates(2 * walker_.cand_id_.size());
    relist(settled);
  }

  void settle(std::uint32_t id, std::uint8_t to) {
    // Candidates are few thousand and sorted by distance; a point is settled once.
    for (Eigen::Index j = 0; j < listed; ++j) {
      if (walker_.cand_id_[static_cast<std::size_t>(j)] == id) {
        if (state[static_cast<std::size_t>(j)] == kOpen) state[static_cast<std::size_t>(j)] = to;
        return;
      }
    }
  }

  // Visits vertex S (sorted): solves it again from S (errors do not accumulate along
  // the walk), its edge directions E = -B^{-1} with rows B_m = s_m - x (column k is
  // orthogonal to every offset but the k-th and points away from s_k), and certifies
  // its new points: for s = S_i, the direction sum_{k != i} E_k keeps x and s
  // equidistant and moves away from the others, into the facet of (x, s); the witness
  // is halfway to the first point met that way. False when S is degenerate.
  bool visit(const std::vector<std::uint32_t>& vertex) {
    SPOKEMESH_INVARIANT(vertex.size() == static_cast<std::size_t>(d) && std::is_sorted(vertex.begin(), vertex.end()),
                        "a vertex is d points, sorted");
    ++out_.vertices;
    for (int m = 0; m < d; ++m) {
      const double* sp = walker_.ps_.point(vertex[m]);
      for (int c = 0; c < d; ++c) B(m, c) = sp[c] - x[c];
      rhs[m] = B.row(m).squaredNorm() / 2;
    }
    Eigen::PartialPivLU<MatrixXd> lu(B);
    E = -lu.inverse();
    v = lu.solve(rhs);
    if (!E.allFinite() || !v.allFinite()) return false;
    bool fresh = false;
    const VectorXd total = E.rowwise().sum();
    for (int i = 0; i < d; ++i) {
      const std::uint32_t s = vertex[i];
      if (found(s) || attempts[s] >= 3) continue;
      f = total - E.col(i);
      // The witness: halfway to the first point met along f (without a hit, as far
      // again as v is from x). The nearest candidates usually give that point already
      // (the witness is then certified by certify()'s own ball query); the full ray is
      // shot only when that fails.
      auto place_witness = [&](bool head_only) {
        double t = 0;
        if (!walker_.shoot(v.data(), f.data(), &s, 1, t, head_only)) {
          t = 2 * std::max(v.norm(), 1e-300) / std::max(f.norm(), 1e-300);
        }
        witness = v + (t / 2) * f;
      };
      place_witness(/*head_only=*/true);
      const bool certified = walker_.certify(s, witness.data());
      if (!certified) place_witness(/*head_only=*/false);
      if (certified ? accept(s) : try_certify(s, witness.data())) {
        fresh = true;
        settle(s, kSettled);
      } else if (attempts[s] >= 3) {
        settle(s, kSettled);
        ++given_up;  // neither certified nor refuted
      }
    }
    misses = fresh ? 0 : misses + 1;
    return true;
  }

  // The target: the open candidate whose bisector is nearest to the current vertex,
  // (|q|^2 - 2 v.q) / (2 |q|) (the constant 2 dropped; recomputed only when the walk
  // has moved). After a few refutations in a row the points about v are spent: the
  // nearest open point to x instead (the likeliest neighbour left), wherever its
  // facet is. States only leave kOpen, so the nearest open point is found from a
  // cursor. -1 when none is open.
  Eigen::Index next_target() {
    Eigen::Index target = -1;
    while (first_open < listed && state[static_cast<std::size_t>(first_open)] != kOpen) ++first_open;
    if (refuted_in_a_row >= kRefutedBeforeNearest) return first_open < listed ? first_open : -1;
    if (slack_at != out_.vertices) {
      const Eigen::Map<const MatrixXd> Q(walker_.cand_q_.data(), d, listed);
      const Eigen::Map<const VectorXd> Q2(walker_.cand_norm2_.data(), listed);
      slack.noalias() = Q2 - 2 * (Q.transpose() * v);
      slack.array() *= inv_norm.array();
      slack_at = out_.vertices;
    }
    for (Eigen::Index j = first_open; j < listed; ++j) {
      if (state[static_cast<std::size_t>(j)] == kOpen && (target < 0 || slack[j] < slack[target])) target = j;
    }
    return target;
  }

  // One target: refuted on the relaxed polytope, reached by an aimed spoke, or walked
  // to by a leg.
  void head_for(Eigen::Index target) {
    SPOKEMESH_INVARIANT(target >= 0 && target < listed && state[static_cast<std::size_t>(target)] == kOpen,
                        "a walk heads for an open listed candidate");
    const std::uint32_t goal = walker_.cand_id_[static_cast<std::size_t>(target)];
    if (std::find(S.begin(), S.end(), goal) != S.end()) {
      // Equidistant at this vertex already, so visit() has tried to certify it (it
      // failed; it may be tried again from another vertex): no leg can reach it.
      state[static_cast<std::size_t>(target)] = kSettled;
      ++given_up;  // neither certified nor refuted
      return;
    }
    if (relaxed_refutes(target)) {
      // Refuted without a leg: a try that found nothing, so a miss like an empty vertex.
      state[static_cast<std::size_t>(target)] = kRefuted;
      ++misses;
      ++refuted_in_a_row;
      return;
    }
    refuted_in_a_row = 0;
    if (aim_ready && aimed_spoke()) return;
    walk_leg(target);
  }

  // The edge (a column of `edges`, which leave a vertex) along which g falls fastest
  // for the target with offset q: rate E_k . q / |E_k|; -1 when none lowers g.
  template <class Offset>
  int steepest_edge(const MatrixXd& edges, const Offset& q) const {
    int best = -1;
    double best_rate = 0;
    for (int k = 0; k < d; ++k) {
      const double norm = edges.col(k).norm();
      const double rate = norm > 0 ? edges.col(k).dot(q) / norm : 0;
      if (rate > best_rate) {
        best_rate = rate;
        best = k;
      }
    }
    return best;
  }

  // The first found neighbour's bisector met along p + t u, t > 0, not counting those
  // in rs (in_rs): (t, index into found_q), or (kInf, -1). r_vq and r_eq hold p . q
  // and u . q for the nf found points.
  std::pair<double, std::int64_t> first_bisector(std::size_t nf) const {
    std::pair<double, std::int64_t> first{kInf, -1};
    for (std::size_t i = 0; i < nf; ++i) {
      if (!(r_eq[i] > 0) || in_rs[i] != 0) continue;
      const double t = (found_q2[i] - 2 * r_vq[i]) / (2 * r_eq[i]);
      if (t > 0 && t < first.first) first = {t, static_cast<std::int64_t>(i)};
    }
    return first;
  }

  // Whether the listed candidate `target` is certainly (in floating point) not a
  // neighbour: the same steepest-edge walk, from the current vertex, over the polytope
  // cut by the bisectors of the found neighbours only (B^{-1} updated by
  // Sherman-Morrison at each step, no tree queries). That polytope contains the cell,
  // so if g stays positive on it, it does on the cell. Its vertices are not Voronoi
  // vertices of x (none is visited or counted); it only spares the walk legs towards
  // points that cannot be reached. When it reaches the target's bisector after
  // kAimAfterSteps steps or more, it sets the aim (r_p) instead.
  bool relaxed_refutes(Eigen::Index target) {
    const auto sd = static_cast<std::size_t>(d);
    const Eigen::Map<const VectorXd> gq(&walker_.cand_q_[static_cast<std::size_t>(target) * sd], d);
    const double gq2 = walker_.cand_norm2_[static_cast<std::size_t>(target)];
    const std::size_t nf = found_q2.size();
    rs.resize(sd);
    for (int m = 0; m < d; ++m) {
      const auto it = found_at.find(S[static_cast<std::size_t>(m)]);
      if (it == found_at.end()) return false;  // an uncertified point: no relaxation
      rs[static_cast<std::size_t>(m)] = it->second;
    }
    in_rs.assign(nf, 0);
    for (const std::uint32_t i : rs) in_rs[i] = 1;
    rE = E;
    rv = v;
    const Eigen::Map<const MatrixXd> F(found_q.data(), d, static_cast<Eigen::Index>(nf));
    // v . q for the found points, kept while the walk stays at v (targets refuted one
    // after another from the same vertex), extended as points are found.
    if (vq_at != out_.vertices) {
      vq_at = out_.vertices;
      v_q.clear();
    }
    if (v_q.size() < nf) {
      const std::size_t from = v_q.size();
      v_q.resize(nf);
      const Eigen::Map<const MatrixXd> Fnew(&found_q[from * sd], d, static_cast<Eigen::Index>(nf - from));
      Eigen::Map<VectorXd>(&v_q[from], static_cast<Eigen::Index>(nf - from)).noalias() = Fnew.transpose() * v;
    }
    r_vq.assign(v_q.begin(), v_q.end());
    double g_vq = gq.dot(rv);
    r_eq.resize(nf);
    for (int step = 0; step < kRelaxedSteps; ++step) {
      const int best = steepest_edge(rE, gq);
      if (best < 0) return true;  // optimal with g > 0
      re = rE.col(best);
      // The first bisector met along rv + t re: the goal's, a found neighbour's, or none.
      Eigen::Map<VectorXd>(r_eq.data(), static_cast<Eigen::Index>(nf)).noalias() = F.transpose() * re;
      const double g_eq = gq.dot(re);
      double t_best = kInf;
      enum class Hit { kNone, kGoal, kFound } hit = Hit::kNone;  // kFound: found_q[hit_index]
      std::int64_t hit_index = 0;
      if (g_eq > 0) {
        const double t = (gq2 - 2 * g_vq) / (2 * g_eq);
        if (t > 0) {
          t_best = t;
          hit = Hit::kGoal;
        }
      }
      if (const auto [t, i] = first_bisector(nf); t < t_best) {
        t_best = t;
        hit = Hit::kFound;
        hit_index = i;
      }
      if (hit == Hit::kGoal && step >= kAimAfterSteps) {
        set_aim(gq, best, t_best, g_eq, nf);
        return false;
      }
      if (hit != Hit::kFound) return false;  // reaches the goal's bisector, or unbounded
      // Move, and swap row `best` of B for the point hit (Sherman-Morrison):
      // B'^{-1} = B^{-1} - (B^{-1} e_k)(delta^T B^{-1}) / (1 + delta^T B^{-1} e_k), so
      // with E = -B^{-1}: E' = E + (E e_k)(delta^T E) / (1 - delta^T E e_k).
      rv += t_best * re;
      for (std::size_t i = 0; i < nf; ++i) r_vq[i] += t_best * r_eq[i];
      g_vq += t_best * g_eq;
      const std::uint32_t out_i = rs[static_cast<std::size_t>(best)], in_i = static_cast<std::uint32_t>(hit_index);
      r_row = Eigen::Map<const VectorXd>(&found_q[in_i * sd], d) - Eigen::Map<const VectorXd>(&found_q[out_i * sd], d);
      r_col = rE.col(best);
      const double denom = 1 - r_row.dot(r_col);
      if (!(std::fabs(denom) > 1e-300)) return false;
      rE.noalias() += (r_col / denom) * (r_row.transpose() * rE);
      in_rs[out_i] = 0;
      in_rs[in_i] = 1;
      rs[static_cast<std::size_t>(best)] = in_i;
      SPOKEMESH_INVARIANT(std::count(in_rs.begin(), in_rs.end(), std::uint8_t{1}) == d,
                          "the relaxed vertex stays on d found bisectors");
      if (!rE.allFinite()) return false;
    }
    return false;
  }

  // A long way to the goal's facet: a leg would be as long. Aim a spoke at that facet
  // instead: p = rv + t re is on it and on the d - 1 bisectors the edge keeps; u keeps
  // g = 0 and leaves those d - 1 (each E_m, m != best, leaves its own and keeps the
  // others; lambda E_best restores g), so p + s u lies inside the goal's facet of the
  // relaxed polytope for 0 < s < (first bisector met). Halfway there is the aim.
  template <class Offset>
  void set_aim(const Offset& gq, int best, double t_best, double g_eq, std::size_t nf) {
    r_p = rv + t_best * re;
    r_u.setZero();
    for (int m = 0; m < d; ++m) {
      if (m != best) r_u += rE.col(m);
    }
    const double lam = -gq.dot(r_u) / g_eq;
    r_u += lam * re;
    for (std::size_t i = 0; i < nf; ++i) r_vq[i] += t_best * r_eq[i];  // now p . q
    const Eigen::Map<const MatrixXd> F(found_q.data(), d, static_cast<Eigen::Index>(nf));
    Eigen::Map<VectorXd>(r_eq.data(), static_cast<Eigen::Index>(nf)).noalias() = F.transpose() * r_u;
    in_rs[rs[static_cast<std::size_t>(best)]] = 0;  // the bisector the edge left may be met
    double t_u = first_bisector(nf).first;
    if (t_u == kInf) t_u = r_p.norm() / std::max(r_u.norm(), 1e-300);
    r_p += (t_u / 2) * r_u;
    aim_ready = r_p.allFinite();
  }

  // The spoke from x towards the aim stays inside the relaxed polytope until it
  // reaches the goal's bisector there, so the first bisector it crosses is the goal's
  // or an unfound point's: a new neighbour (in exact arithmetic), certified at the
  // spoke's end like any spoke. The walk then moves to that facet: recursive spokes
  // inside it from the spoke's end down to a vertex (Sec. 3.2), visited as usual, so
  // the next targets are chosen about it. False if any of it fails (the leg is walked
  // as before).
  bool aimed_spoke() {
    aim_ready = false;
    double t = 0;
    const std::optional<std::uint32_t> hit = walker_.shoot(origin.data(), r_p.data(), nullptr, 0, t);
    if (!hit || found(*hit)) return false;
    witness = t * r_p;
    if (!try_certify(*hit, witness.data())) return false;
    settle(*hit, kSettled);
    misses = 0;
    kept_S = S;
    kept_v = v;
    kept_E = E;
    if (!descend(witness.data(), *hit) || !visit(S)) {  // stay at the vertex we were at
      S.swap(kept_S);
      v = kept_v;
      E = kept_E;
    }
    return true;
  }

  // A leg: steepest edges towards the target until it is met, refuted (no edge lowers
  // g) or the leg's budget is spent.
  void walk_leg(Eigen::Index target) {
    const std::uint32_t goal = walker_.cand_id_[static_cast<std::size_t>(target)];
    const Eigen::Map<const VectorXd> q(&walker_.cand_q_[static_cast<std::size_t>(target) * d], d);
    bool reached_goal = false;
    for (int step = 0; step < kStepsPerTarget && !reached_goal; ++step) {
      if (budget_spent() || walker_.stop_requested()) break;
      // The steepest edge towards the goal (g falls along E_k at the rate -2 E_k . q).
      const int best = steepest_edge(E, q);
      if (best < 0) break;  // no edge lowers g: the goal is not a neighbour
      e = E.col(best);
      double t = 0;
      const std::optional<std::uint32_t> hit = walker_.shoot(v.data(), e.data(), S.data(), d, t);
      if (!hit) break;  // unbounded: cannot happen with the goal listed
      SPOKEMESH_INVARIANT(std::find(S.begin(), S.end(), *hit) == S.end(), "an edge leaves its vertex's points");
      next = S;
      next[static_cast<std::size_t>(best)] = *hit;
      std::sort(next.begin(), next.end());
      S.swap(next);
      at_vertex = visit(S);
      if (!at_vertex) break;
      reached_goal = *hit == goal;
    }
    if (!reached_goal && at_vertex && state[static_cast<std::size_t>(target)] == kOpen && !budget_spent()) {
      state[static_cast<std::size_t>(target)] = kRefuted;
    }
    if (reached_goal) settle(goal, kSettled);
  }

  ApproxWalker& walker_;
  ApproxNeighbors& out_;
  const int d;
  const double* x;  // the seed
  // The current vertex: its d equidistant points (sorted), found by descend or a leg.
  std::vector<std::uint32_t> S, next;
  VectorXd y;                                       // where a descent's spoke starts
  std::unordered_map<std::uint32_t, int> attempts;  // failed certifications per point
  bool descent_found = false;                       // the last descent certified a new neighbour
  // The certified neighbours: id -> index in found_q, their offsets s - x (d per
  // point), and found_q2, their |s - x|^2.
  std::unordered_map<std::uint32_t, std::uint32_t> found_at;
  std::vector<double> found_q, found_q2;
  double outer2 = kInf;  // see relist
  std::size_t outer_found = 0;
  bool list_more = false;
  // The candidate list: its length, a state per candidate, and the slack of each
  // bisector at the vertex visited slack_at-th (inv_norm: 1 / |q|).
  Eigen::Index listed = 0;
  std::vector<std::uint8_t> state;
  std::uint64_t slack_at = ~std::uint64_t{0};
  VectorXd slack, inv_norm;
  Eigen::Index first_open = 0;  // no open candidate before it
  // The vertex v, its offsets B, its edge directions E, and scratch vectors.
  MatrixXd B, E;
  VectorXd v, f, e, witness, rhs;
  std::uint64_t misses = 0;
  bool at_vertex = false;
  int refuted_in_a_row = 0;
  std::size_t given_up = 0;  // targets settled neither certified nor refuted
  // The relaxed walk: rs (indices into found_q) and in_rs (per found point) its
  // vertex, r_vq and r_eq (per found point) rv . q and re . q, v_q (per found point)
  // v . q at the vertex visited vq_at-th; rE its edges, -(rs's offsets as rows)^{-1}.
  std::vector<std::uint32_t> rs;
  std::vector<std::uint8_t> in_rs;
  std::vector<double> r_vq, r_eq, v_q;
  std::uint64_t vq_at = ~std::uint64_t{0};
  MatrixXd rE;
  VectorXd rv, re, r_row, r_col;
  // Set by relaxed_refutes when the goal's facet is far: r_p, a point inside it (the aim).
  bool aim_ready = false;
  VectorXd r_p, r_u, kept_v;
  const VectorXd origin;  // x, where aimed spokes start
  MatrixXd kept_E;
  std::vector<std::uint32_t> kept_S;
};

Status ApproxWalker::compute_rsd(ApproxNeighbors& out) { return RsdWalk(*this, out).run(); }

Result<NeighborMode> parse_neighbor_mode(std::string_view text, std::string_view field) {
  if (text == "exact") return NeighborMode::kExact;
  if (text == "approximate" || text == "rsd") return NeighborMode::kApproximate;
  if (text == "spokes") return NeighborMode::kSpokes;
  return invalid_argument(std::string(field) + ": \"" + std::string(text.substr(0, 40)) +
                          "\" is not exact, approximate (rsd) or spokes");
}

const char* neighbor_mode_name(NeighborMode mode) {
  switch (mode) {
    case NeighborMode::kExact:
      return "exact";
    case NeighborMode::kApproximate:
      return "approximate";
    case NeighborMode::kSpokes:
      return "spokes";
  }
  return "exact";
}

ApproxOptions::Mode approx_walk(NeighborMode mode) {
  return mode == NeighborMode::kSpokes ? ApproxOptions::Mode::kSpokes : ApproxOptions::Mode::kRsd;
}

}  // namespace spokemesh
