// The star walk in 2-d (see StarWalker::RingWalk in ring_walk.hpp).
#include "walks/ring_walk.hpp"

#include <algorithm>
#include <array>

#include "base/invariant.hpp"

namespace spokemesh {

// The star in 2-d. x's star is a ring of triangles about x, each two consecutive
// neighbours and x (a path, ended by two hull edges, when x is on the convex hull), so
// the walk keeps each neighbour with its two neighbours in the ring: the link of x. The
// EdgeCache's posts fill in runs of the ring; a start by spokes fills one triangle.
// Each neighbour with one side still unknown then wraps about its edge with x, away
// from the side it knows, and the walk goes on from the point hit until it meets the
// other end of the gap (known, so it stops) or the hull. Every triangle but the first
// costs one wrap, every hull edge one wrap that finds nothing (as the general walk's
// spanning tree, without its hashing: in a ring, the point hit is either new or the
// end of an open gap).
Status StarWalker::RingWalk::compute(Star& out, StarPart part) {
  constexpr std::uint32_t kUnknown = 0xFFFFFFFEu, kHull = EdgeCache::kHull;
  EdgeCache* const cache = w_.options_.edges;
  ring_.clear();
  ring_open_.clear();
  ring_triangles_.clear();
  std::size_t hull = 0;
  // The node of a neighbour, added if new; only the posts' few ids are searched.
  auto add_node = [&](std::uint32_t id) {
    __builtin_prefetch(w_.ps_.point(id));
    if (cache != nullptr && cache->wanted(w_.x_, id)) cache->prefetch(id, /*for_post=*/true);
    ring_.push_back(RingNode{id, {kUnknown, kUnknown}, false});
    return static_cast<std::uint32_t>(ring_.size() - 1);
  };
  auto node_of = [&](std::uint32_t id) {
    for (std::uint32_t i = 0; i < ring_.size(); ++i) {
      if (ring_[i].id == id) return i;
    }
    return add_node(id);
  };
  // Sets one unknown side of node u to `id` (a neighbour or kHull); false when u has no
  // unknown side left, which exact answers never cause.
  auto set_side = [&](std::uint32_t u, std::uint32_t id) {
    RingNode& node = ring_[u];
    const int k = node.side[0] == kUnknown ? 0 : node.side[1] == kUnknown ? 1 : -1;
    if (k < 0) return false;
    node.side[k] = id;
    if (id == kHull) ++hull;
    return true;
  };
  // The triangle x, u, v (nodes), unless known.
  auto link = [&](std::uint32_t u, std::uint32_t v) {
    const std::uint32_t a = ring_[u].id, b = ring_[v].id;
    if (ring_[u].side[0] == b || ring_[u].side[1] == b) return true;
    if (!set_side(u, b) || !set_side(v, a)) return false;
    ring_triangles_.push_back(a < b ? std::uint64_t{a} << 32 | b : std::uint64_t{b} << 32 | a);
    return true;
  };
  const auto inconsistent = [] { return internal_error("inconsistent triangles in a 2-d star (three on one edge)"); };

  // A start: the posts of earlier stars, or recursive spokes.
  std::array<BoundedDouble, 3> first_plane;
  std::array<std::uint32_t, 2> first{kUnknown, kUnknown};  // the spoke triangle, if any
  std::array<EdgeCache::Post, EdgeCache::kPostsPerPoint> posts;
  const int post_count = cache != nullptr ? cache->read(w_.x_, posts.data()) : 0;
  for (int i = 0; i < post_count; ++i) {
    const EdgeCache::Post& post = posts[static_cast<std::size_t>(i)];
    const std::uint32_t from = node_of(post.from);
    ring_[from].sender = true;
    for (const std::uint32_t apex : {post.a, post.b}) {
      if (apex == kHull) {
        if (!set_side(from, kHull)) return inconsistent();
      } else if (!link(from, node_of(apex))) {
        return inconsistent();
      }
    }
  }
  if (post_count > 0) {
    ++w_.stats_.cached_starts;
    w_.stats_.cached_wraps += static_cast<std::uint64_t>(post_count);
  } else {
    bool hidden = false;
    if (Status s = w_.first_simplex(first.data(), first_plane.data(), hidden); !s.is_ok()) return s;
    if (hidden) {  // with weights: x is in no triangle
      out.seed = w_.x_;
      out.dimension = 2;
      out.hull_facets = 0;
      out.hidden = true;
      out.simplices.clear();
      return Status::ok();
    }
    if (!link(add_node(first[0]), add_node(first[1]))) return inconsistent();
  }
  for (std::uint32_t i = 0; i < ring_.size(); ++i) {
    if (ring_[i].side[1] == kUnknown) ring_open_.push_back(i);
  }

  // Close the gaps, each from one end.
  std::array<BoundedDouble, 3> plane, hit_plane;
  std::array<Row, 1> pivot;
  for (const std::uint32_t start : ring_open_) {
    if (ring_[start].side[1] != kUnknown) continue;  // closed from its gap's other end
    std::uint32_t u = start;
    std::uint32_t from = ring_[u].side[0];
    {
      const std::uint32_t ids[2] = {std::min(from, ring_[u].id), std::max(from, ring_[u].id)};
      if (ids[0] == std::min(first[0], first[1]) && ids[1] == std::max(first[0], first[1])) {
        plane = first_plane;
      } else {
        w_.simplex_plane(ids, plane.data());
      }
    }
    for (;;) {
      w_.prepare_wrap();
      pivot[0] = Row::of_point(ring_[u].id);
      const WrapResult hit = w_.wrap(pivot.data(), Side{.away_from = from}, plane.data(), hit_plane.data());
      if (hit.kind == WrapResult::Kind::kCancelled) return w_.stopped();
      if (!hit.is_hit()) {
        if (!set_side(u, kHull)) return inconsistent();
        break;
      }
      const std::uint32_t id = hit.point;
      std::uint32_t v = kUnknown;
      for (const std::uint32_t o : ring_open_) {
        if (ring_[o].id == id && ring_[o].side[1] == kUnknown) v = o;
      }
      if (v != kUnknown) {  // the gap's other end
        if (!link(u, v)) return inconsistent();
        break;
      }
      if (ring_.size() >= w_.ps_.size()) return inconsistent();  // a ring longer than the set
      v = add_node(id);
      if (!link(u, v)) return inconsistent();
      from = ring_[u].id;
      u = v;
      plane = hit_plane;
    }
  }

#ifdef SPOKEMESH_CHECK_INVARIANTS
  // A closed ring has as many triangles as neighbours; a path (x on the hull) one
  // fewer, and ends at two hull edges.
  for (const RingNode& node : ring_) {
    SPOKEMESH_INVARIANT(node.side[0] != kUnknown && node.side[1] != kUnknown, "every neighbour's ring sides are known");
  }
  SPOKEMESH_INVARIANT((hull == 0 && ring_triangles_.size() == ring_.size()) ||
                          (hull == 2 && ring_triangles_.size() + 1 == ring_.size()),
                      "x's link is a cycle, or a path between two hull edges");
#endif
  // Posts to the neighbours still to come: x's triangles on either side of each.
  if (cache != nullptr) {
    for (const RingNode& node : ring_) {
      if (!node.sender && cache->wanted(w_.x_, node.id)) cache->post(node.id, {w_.x_, node.side[0], node.side[1]});
    }
  }

  // Canonical output. The whole star (kAll, kWhole) as any star's; the owned triangles
  // (the whole mesh's hot path) are x, low, high with x < low, so sorting (low, high)
  // words orders them.
  if (part != StarPart::kOwned) {
    w_.work_.clear();
    for (const std::uint64_t t : ring_triangles_) {
      w_.work_.push_back(static_cast<std::uint32_t>(t >> 32));
      w_.work_.push_back(static_cast<std::uint32_t>(t));
    }
    w_.emit_canonical(hull, part, out);
    return Status::ok();
  }
  std::sort(ring_triangles_.begin(), ring_triangles_.end());
  out.seed = w_.x_;
  out.dimension = 2;
  out.hull_facets = hull;
  out.simplices.clear();
  for (const std::uint64_t t : ring_triangles_) {
    const auto low = static_cast<std::uint32_t>(t >> 32), high = static_cast<std::uint32_t>(t);
    if (low < w_.x_) continue;
    out.simplices.insert(out.simplices.end(), {w_.x_, low, high});
  }
  w_.orient_positively(out);
  return Status::ok();
}

}  // namespace spokemesh
