#include "spokemesh/certify.hpp"

#include "base/dimension.hpp"
#include "mesh/ball_bounds.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <vector>

namespace spokemesh {

namespace {

using namespace ball_bounds;

// Whether the ball (centre interval, radius^2 <= radius2_up) lies inside ball h (d
// centre coordinates, then its radius).
template <int D>
bool inside_ball(const std::array<Interval, D>& centre, double radius2_up, const double* h) {
  double far2 = 0;
  for (int k = 0; k < D; ++k) {
    const double far = std::max(std::fabs(centre[k].lo - h[k]), std::fabs(centre[k].hi - h[k]));
    far2 += up(far) * up(far);
  }
  return up(up(std::sqrt(up(far2))) + up(std::sqrt(radius2_up))) <= h[D];
}

// The sign of det[f_1 - s, ..., f_{D-1} - s, q - s] when the filter decides it, else 0.
template <int D>
int side(const double* s, const std::array<const double*, D - 1>& f, const double* q) {
  std::array<std::array<double, D>, D> a{};
  for (int i = 0; i < D - 1; ++i) {
    for (int k = 0; k < D; ++k) a[i][k] = f[i][k] - s[k];
  }
  for (int k = 0; k < D; ++k) a[D - 1][k] = q[k] - s[k];
  Filtered det;
  if constexpr (D == 2) {
    det = {a[0][0] * a[1][1] - a[0][1] * a[1][0], std::fabs(a[0][0] * a[1][1]) + std::fabs(a[0][1] * a[1][0])};
  } else {
    double v = 0, m = 0;
    for (int k = 0; k < 3; ++k) {
      const int k1 = (k + 1) % 3, k2 = (k + 2) % 3;
      const double minor = a[1][k1] * a[2][k2] - a[1][k2] * a[2][k1];
      const double minor_mag = std::fabs(a[1][k1] * a[2][k2]) + std::fabs(a[1][k2] * a[2][k1]);
      v += a[0][k] * minor;
      m += std::fabs(a[0][k]) * minor_mag;
    }
    det = {v, m};
  }
  const Interval i = det.interval();
  return i.lo > 0 ? 1 : i.hi < 0 ? -1 : 0;
}

template <int D>
StarCertificate certify(const PointSet& ps, const double* global, const Star& star, std::span<const double> held_boxes,
                        std::span<const double> held_balls, std::span<const double> unheld,
                        const std::function<bool(std::span<const std::uint32_t>)>& known_hull) {
  StarCertificate out;
  const std::size_t box_words = 2 * D, boxes = unheld.size() / box_words;
  const double* s = ps.point(star.seed);
  const std::size_t w = D + 1;
  bool failed = false;
  // Hull facets: the facets through the seed that only one simplex of the star has.
  struct Facet {
    std::array<std::uint32_t, D> vertices;  // ascending, the seed among them
    std::uint32_t apex;                     // the simplex's vertex off the facet
  };
  std::vector<Facet> facets;
  facets.reserve(star.hull_facets != 0 ? star.size() * D : 0);
  for (std::size_t t = 0; t < star.size(); ++t) {
    const std::uint32_t* simplex = star.simplex(t);
    std::array<const double*, D> v{};
    int at = 0;
    for (std::size_t j = 0; j < w; ++j) {
      if (simplex[j] != star.seed) v[static_cast<std::size_t>(at++)] = ps.point(simplex[j]);
    }
    // The ball: by the filtered bounds, or (a nearly flat simplex, which they cannot
    // place) exactly, so that it is certified once its points are held, as any other.
    std::array<Interval, D> centre{};
    double radius2 = 0;
    if (!circumball<D>(s, v, centre, radius2)) exact_circumball<D>(s, v, centre, radius2);
    bool ok = true;
    std::array<double, 2 * D> extent{};
    // Most balls lie well inside the first held box: the ball's own box says so.
    bool held = false;
    if (!held_boxes.empty()) {
      const double r = up(std::sqrt(radius2));
      held = true;
      for (int k = 0; k < D && held; ++k) {
        held = down(centre[k].lo - r) >= held_boxes[static_cast<std::size_t>(k)] &&
               up(centre[k].hi + r) <= held_boxes[static_cast<std::size_t>(D + k)];
      }
    }
    if (!held) {
      extent = clipped_extent<D>(centre, radius2, global);
      for (std::size_t b = 0; b + box_words <= held_boxes.size() && !held; b += box_words) {
        held = inside<D>(extent, held_boxes.data() + b);
      }
    }
    for (std::size_t b = 0; b < boxes && ok && !held; ++b)
      ok = misses<D>(centre, radius2, unheld.data() + b * box_words);
    // (The held balls, often many, last: most balls miss every unheld box.)
    for (std::size_t b = 0; b + D + 1 <= held_balls.size() && !ok; b += D + 1) {
      ok = inside_ball<D>(centre, radius2, held_balls.data() + b);
    }
    if (!ok) {
      // Ask for the ball itself: a ball query returns only what lies inside (near the
      // hull a ball's part of the set's box is a wide thin cap, a box around it many
      // points).
      failed = true;
      double spread2 = 0;
      for (int k = 0; k < D; ++k) {
        const double mid = centre[k].lo / 2 + centre[k].hi / 2;
        out.balls.push_back(mid);
        const double half = std::max(up(centre[k].hi - mid), up(mid - centre[k].lo));
        spread2 += half * half;
      }
      out.balls.push_back(up(up(up(std::sqrt(radius2)) + up(std::sqrt(up(spread2)))) * (1 + 1e-12)));
    }
    if (star.hull_facets == 0) continue;
    for (std::size_t skip = 0; skip < w; ++skip) {
      if (simplex[skip] == star.seed) continue;
      Facet f{};
      int k = 0;
      for (std::size_t j = 0; j < w; ++j) {
        if (j != skip) f.vertices[static_cast<std::size_t>(k++)] = simplex[j];
      }
      std::sort(f.vertices.begin(), f.vertices.end());
      f.apex = simplex[skip];
      facets.push_back(f);
    }
  }
  std::sort(facets.begin(), facets.end(), [](const Facet& a, const Facet& b) { return a.vertices < b.vertices; });
  for (std::size_t i = 0; i < facets.size();) {
    std::size_t j = i + 1;
    while (j < facets.size() && facets[j].vertices == facets[i].vertices) ++j;
    if (j - i == 1 && !known_hull(facets[i].vertices)) {  // a hull facet: its outer side must miss every unheld box
      std::array<const double*, D> f{};
      for (int k = 0; k < D; ++k)
        f[static_cast<std::size_t>(k)] = ps.point(facets[i].vertices[static_cast<std::size_t>(k)]);
      bool ok = true;
      for (std::size_t b = 0; b < boxes && ok; ++b) {
        ok = !StarCertifier::may_be_beyond(D, f.data(), ps.point(facets[i].apex), unheld.data() + b * box_words);
      }
      if (!ok) {
        out.hull_facets.insert(out.hull_facets.end(), facets[i].vertices.begin(), facets[i].vertices.end());
        out.hull_facets.push_back(facets[i].apex);
      }
    }
    i = j;
  }
  out.certified = !failed && out.hull_facets.empty();
  return out;
}

// The filtered orientation of q against the facet through f (side<D> with the facet's
// first point as the origin).
template <int D>
int facet_side(const double* const* f, const double* q) {
  std::array<const double*, D - 1> rest{};
  for (int k = 1; k < D; ++k) rest[static_cast<std::size_t>(k - 1)] = f[k];
  return side<D>(f[0], rest, q);
}

template <int D>
bool beyond_box(const double* const* f, const double* inner, const double* box) {
  const int in = facet_side<D>(f, inner);
  if (in == 0) return true;
  for (unsigned corner = 0; corner < (1u << D); ++corner) {
    std::array<double, D> q{};
    for (int k = 0; k < D; ++k) q[static_cast<std::size_t>(k)] = box[(corner >> k & 1u) != 0 ? D + k : k];
    if (facet_side<D>(f, q.data()) != in) return true;
  }
  return false;
}

}  // namespace

StarCertificate StarCertifier::certify(const Star& star, std::span<const double> held_boxes,
                                       std::span<const double> held_balls, std::span<const double> unheld,
                                       const std::function<bool(std::span<const std::uint32_t>)>& known_hull) const {
  if (unheld.empty()) {
    StarCertificate all_held;
    all_held.certified = true;
    return all_held;
  }
  // Certified in 2-d and 3-d only: elsewhere nothing is.
  return detail::dispatch_2d_3d(points_.dimension(), StarCertificate{}, [&](auto dim) {
    constexpr int D = decltype(dim)::value;
    return spokemesh::certify<D>(points_, global_.data(), star, held_boxes, held_balls, unheld, known_hull);
  });
}

namespace {

// StarCertifier::ball_is_held in D dimensions: the ball's centre is exact.
template <int D>
bool ball_is_held(const double* s, double radius2, const double* global, std::span<const double> held_boxes,
                  std::span<const double> held_balls, std::span<const double> unheld) {
  std::array<Interval, D> centre{};
  for (int k = 0; k < D; ++k) centre[static_cast<std::size_t>(k)] = {s[k], s[k]};
  const double r2 = up(radius2);
  const std::array<double, 2 * D> extent = clipped_extent<D>(centre, r2, global);
  for (std::size_t b = 0; b + 2 * D <= held_boxes.size(); b += 2 * D) {
    if (inside<D>(extent, held_boxes.data() + b)) return true;
  }
  for (std::size_t b = 0; b + D + 1 <= held_balls.size(); b += D + 1) {
    if (inside_ball<D>(centre, r2, held_balls.data() + b)) return true;
  }
  for (std::size_t b = 0; b + 2 * D <= unheld.size(); b += 2 * D) {
    if (!misses<D>(centre, r2, unheld.data() + b)) return false;
  }
  return true;
}

}  // namespace

bool StarCertifier::ball_is_held(std::uint32_t seed, double radius2, std::span<const double> held_boxes,
                                 std::span<const double> held_balls, std::span<const double> unheld) const {
  if (unheld.empty()) return true;
  const double* s = points_.point(seed);
  return detail::dispatch_2d_3d(points_.dimension(), false, [&](auto dim) {
    constexpr int D = decltype(dim)::value;
    return spokemesh::ball_is_held<D>(s, radius2, global_.data(), held_boxes, held_balls, unheld);
  });
}

HeldRegion::HeldRegion(int d, std::vector<double> whole_box, std::uint64_t whole_points)
    : d_(d), whole_(std::move(whole_box)), whole_points_(whole_points) {}

void HeldRegion::add_held_box(std::span<const double> box) {
  held_boxes_.insert(held_boxes_.end(), box.begin(), box.end());
}

void HeldRegion::add_held_ball(std::span<const double> ball) {
  held_balls_.insert(held_balls_.end(), ball.begin(), ball.end());
}

void HeldRegion::add_unheld_box(std::span<const double> box, std::uint64_t points) {
  unheld_.push_back({std::vector<double>(box.begin(), box.end()), points});
}

namespace {

// The volume of a box (2 d doubles); 0 for a flat one.
double box_volume(int d, const double* b) {
  double v = 1;
  for (int c = 0; c < d; ++c) v *= std::max(0.0, b[d + c] - b[c]);
  return v;
}

// Box `rest` less box q, as closed boxes appended to `out` (a face shared with q is
// kept in both: conservative).
void subtract_box(int d, std::vector<double> rest, const double* q, std::vector<std::vector<double>>& out) {
  const auto dd = static_cast<std::size_t>(d);
  for (std::size_t c = 0; c < dd; ++c) {
    if (q[dd + c] < rest[c] || q[c] > rest[dd + c]) {  // q misses what is left
      out.push_back(std::move(rest));
      return;
    }
  }
  for (std::size_t c = 0; c < dd; ++c) {
    if (rest[c] < q[c]) {  // the part below q along c
      std::vector<double> part = rest;
      part[dd + c] = q[c];
      out.push_back(std::move(part));
    }
    if (rest[dd + c] > q[dd + c]) {
      std::vector<double> part = rest;
      part[c] = q[dd + c];
      out.push_back(std::move(part));
    }
    rest[c] = std::max(rest[c], q[c]);
    rest[dd + c] = std::min(rest[dd + c], q[dd + c]);
  }
}

}  // namespace

void HeldRegion::freeze() {
  residual_boxes_.clear();
  // Each unheld box less every held box, piece by piece; a box that would break into
  // more than kMostPieces stays as far as it got (more residual: only more fetching).
  constexpr std::size_t kMostPieces = 256;
  const auto w = static_cast<std::size_t>(2 * d_);
  residual_.clear();
  for (const Unheld& u : unheld_) {
    std::vector<std::vector<double>> parts{u.box}, next;
    for (std::size_t h = 0; h + w <= held_boxes_.size() && !parts.empty(); h += w) {
      next.clear();
      for (std::vector<double>& part : parts) subtract_box(d_, std::move(part), &held_boxes_[h], next);
      if (next.size() > kMostPieces) {
        parts = {u.box};  // too fragmented: kept whole (conservative)
        break;
      }
      parts.swap(next);
    }
    const double volume = box_volume(d_, u.box.data());
    for (std::vector<double>& part : parts) {
      const double share = volume > 0 ? box_volume(d_, part.data()) / volume : 1.0;
      residual_boxes_.insert(residual_boxes_.end(), part.begin(), part.end());
      residual_.push_back({std::move(part), share * static_cast<double>(u.points)});
    }
  }
}

StarCertificate HeldRegion::certify(const PointSet& points, const Star& star) const {
  if (residual_.empty()) {
    StarCertificate all_held;
    all_held.certified = true;
    return all_held;
  }
  const auto known = [&](std::span<const std::uint32_t> facet) { return known_hull_ && known_hull_(facet); };
  return detail::dispatch_2d_3d(d_, StarCertificate{}, [&](auto dim) {
    constexpr int D = decltype(dim)::value;
    return spokemesh::certify<D>(points, whole_.data(), star, {}, held_balls_, residual_boxes_, known);
  });
}

const double* HeldRegion::residual_meeting(const double* box) const {
  const auto dd = static_cast<std::size_t>(d_);
  for (const Residual& r : residual_) {
    bool meets = true;
    for (std::size_t c = 0; c < dd && meets; ++c) meets = !(box[dd + c] < r.box[c] || box[c] > r.box[dd + c]);
    if (meets) return r.box.data();
  }
  return nullptr;
}

bool HeldRegion::ball_held(const double* centre_lo, const double* centre_hi, double radius2_up) const {
  if (residual_.empty()) return true;
  return detail::dispatch_2d_3d(d_, false, [&](auto dim) {
    constexpr int D = decltype(dim)::value;
    std::array<Interval, D> centre{};
    for (int k = 0; k < D; ++k) centre[static_cast<std::size_t>(k)] = {centre_lo[k], centre_hi[k]};
    bool misses_all = true;
    for (const Residual& r : residual_) {
      if (!misses<D>(centre, radius2_up, r.box.data())) {
        misses_all = false;
        break;
      }
    }
    if (misses_all) return true;
    for (std::size_t b = 0; b + D + 1 <= held_balls_.size(); b += D + 1) {
      if (inside_ball<D>(centre, radius2_up, held_balls_.data() + b)) return true;
    }
    return false;
  });
}

bool HeldRegion::beyond_held(const double* const* f, const double* inner, std::span<const std::uint32_t> ids) const {
  if (residual_.empty()) return true;
  if (d_ != 2 && d_ != 3) return false;
  for (const Residual& r : residual_) {
    if (StarCertifier::may_be_beyond(d_, f, inner, r.box.data())) return known_hull_ && known_hull_(ids);
  }
  return true;
}

double HeldRegion::lacking_in(const double* box) const {
  const auto dd = static_cast<std::size_t>(d_);
  double total = 0;
  for (const Residual& r : residual_) {
    double share = 1;
    const double volume = box_volume(d_, r.box.data());
    for (std::size_t c = 0; c < dd && share > 0; ++c) {
      const double lo = std::max(box[c], r.box[c]), hi = std::min(box[dd + c], r.box[dd + c]);
      if (hi < lo) share = 0;
      if (volume > 0) share *= (hi - lo) / (r.box[dd + c] - r.box[c]);
    }
    total += share * r.points;
  }
  return total;
}

bool StarCertifier::may_be_beyond(int d, const double* const* f, const double* inner, const double* box) {
  return detail::dispatch_2d_3d(d, true, [&](auto dim) { return beyond_box<decltype(dim)::value>(f, inner, box); });
}

bool StarCertifier::may_be_beyond_point(int d, const double* const* f, const double* inner, const double* q) {
  return detail::dispatch_2d_3d(d, true, [&](auto dim) {
    constexpr int D = decltype(dim)::value;
    const int in = facet_side<D>(f, inner), at = facet_side<D>(f, q);
    return in == 0 || at != in;
  });
}

}  // namespace spokemesh
