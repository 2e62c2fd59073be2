#include "spokemesh/voronoi.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>

namespace spokemesh {

std::vector<double> circumcentre(const PointSet& points, const std::uint32_t* ids, int count) {
  // c = p0 + sum_i l_i v_i with v_i = p_i - p0 and G l = b / 2, G = V V^T, b_i = |v_i|^2.
  const int d = points.dimension();
  const int k = count - 1;
  const double* p0 = points.point(ids[0]);
  Eigen::MatrixXd v(k, d);
  for (int i = 0; i < k; ++i) {
    for (int c = 0; c < d; ++c) v(i, c) = points.point(ids[i + 1])[c] - p0[c];
  }
  std::vector<double> centre(p0, p0 + d);
  if (k == 0) return centre;
  const Eigen::MatrixXd gram = v * v.transpose();
  const Eigen::VectorXd b = v.rowwise().squaredNorm() * 0.5;
  const Eigen::VectorXd lambda = gram.fullPivLu().solve(b);
  const Eigen::VectorXd offset = v.transpose() * lambda;
  for (int c = 0; c < d; ++c) centre[c] += offset(c);
  return centre;
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

namespace {

double distance2(const double* a, const double* b, int d) {
  double s = 0;
  for (int c = 0; c < d; ++c) s += (a[c] - b[c]) * (a[c] - b[c]);
  return s;
}

// Signed (d - k)-volume of the Voronoi face dual to the Delaunay face `face`
// (k + 1 sorted ids including the seed), by the pyramid decomposition.
class FaceVolumes {
 public:
  FaceVolumes(const PointSet& ps, const Star& star) : ps_(ps), star_(star), d_(ps.dimension()) {}

  double volume(const std::vector<std::uint32_t>& face) {
    const int k = static_cast<int>(face.size()) - 1;
    if (k == d_) return 1.0;
    if (auto it = memo_.find(face); it != memo_.end()) return it->second;
    const std::vector<double> c = centre(face);
    // Children: faces with one more vertex, taken from the star simplices containing `face`.
    std::vector<std::uint32_t> extra;
    for (std::size_t i = 0; i < star_.size(); ++i) {
      // Star simplices are not sorted within (positive orientation), hence find.
      const std::uint32_t* s = star_.simplex(i);
      if (!std::all_of(face.begin(), face.end(), [&](std::uint32_t v) { return std::find(s, s + d_ + 1, v) != s + d_ + 1; })) {
        continue;
      }
      for (int j = 0; j <= d_; ++j) {
        if (!std::binary_search(face.begin(), face.end(), s[j])) extra.push_back(s[j]);
      }
    }
    std::sort(extra.begin(), extra.end());
    extra.erase(std::unique(extra.begin(), extra.end()), extra.end());
    double total = 0;
    for (std::uint32_t j : extra) {
      std::vector<std::uint32_t> child = face;
      child.insert(std::upper_bound(child.begin(), child.end(), j), j);
      const std::vector<double> cc = centre(child);
      const double height = std::sqrt(distance2(c.data(), cc.data(), d_));
      // Positive where c lies on the cell's side of the child face: closer to the
      // face's points than to j.
      const double own = distance2(c.data(), ps_.point(face[0]), d_);
      const double other = distance2(c.data(), ps_.point(j), d_);
      const double sign = other >= own ? 1.0 : -1.0;
      total += sign * height * volume(child) / (d_ - k);
    }
    memo_.emplace(face, total);
    return total;
  }

 private:
  std::vector<double> centre(const std::vector<std::uint32_t>& face) {
    return circumcentre(ps_, face.data(), static_cast<int>(face.size()));
  }
  const PointSet& ps_;
  const Star& star_;
  int d_;
  std::map<std::vector<std::uint32_t>, double> memo_;
};

}  // namespace

VoronoiCell voronoi_cell(const PointSet& points, const Star& star) {
  VoronoiCell cell;
  const int d = points.dimension();
  cell.seed = star.seed;
  cell.dimension = d;
  cell.bounded = star.bounded_cell();
  const std::size_t m = star.size();
  cell.vertex_simplices = star.simplices;
  cell.vertices.reserve(m * d);
  for (std::size_t i = 0; i < m; ++i) {
    const std::vector<double> c = circumcentre(points, star.simplex(i), d + 1);
    cell.vertices.insert(cell.vertices.end(), c.begin(), c.end());
  }
  for (std::uint32_t j : star_neighbors(star)) {
    VoronoiFacet facet;
    facet.neighbor = j;
    for (std::size_t i = 0; i < m; ++i) {
      const std::uint32_t* s = star.simplex(i);
      if (std::find(s, s + d + 1, j) != s + d + 1) facet.vertices.push_back(static_cast<std::uint32_t>(i));
    }
    cell.facets.push_back(std::move(facet));
  }
  if (cell.bounded) {
    FaceVolumes volumes(points, star);
    cell.volume = volumes.volume({star.seed});
  } else {
    cell.volume = std::numeric_limits<double>::infinity();
  }
  return cell;
}

}  // namespace spokemesh
