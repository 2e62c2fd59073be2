// Internal to core: the deterministic random numbers, the index-tuple hash and sort
// shared by the exact star walk, the approximate neighbour walk and the validator.
#pragma once

#include <cstddef>
#include <cstdint>

namespace spokemesh::detail {

// splitmix64: platform-independent random numbers (std distributions are
// implementation-defined, and a replica must draw the same spokes anywhere).
inline std::uint64_t splitmix64(std::uint64_t& state) {
  std::uint64_t z = (state += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

// The per-seed random state: the caller's seed mixed with the seed index.
inline std::uint64_t seed_state(std::uint64_t random_seed, std::uint32_t seed) {
  return random_seed ^ (0xD1B54A32D192ED03ull * (std::uint64_t{seed} + 1));
}

// Insertion sort for the 1..9 indices of a simplex or facet key (std::sort's set-up
// costs more than the sort at this size, and GCC 12 warns falsely about its heap
// code on a std::array of 9).
inline void sort_small(std::uint32_t* a, int n) {
  for (int i = 1; i < n; ++i) {
    const std::uint32_t v = a[i];
    int j = i;
    for (; j > 0 && a[j - 1] > v; --j) a[j] = a[j - 1];
    a[j] = v;
  }
}

// Hash of a tuple of point indices (FNV-style with a shift-add mix).
inline std::uint64_t hash_indices(const std::uint32_t* key, std::size_t length) {
  std::uint64_t h = 0x84222325CBF29CE4ull;
  for (std::size_t i = 0; i < length; ++i) h = (h ^ key[i]) * 0x100000001B3ull + (h >> 29);
  return h ^ (h >> 32);
}

// A hash of a set of point indices that can drop a member in O(1): the sum (mod 2^64)
// of each index mixed by splitmix64's finalizer, mixed once more. A facet's hash is
// set_hash_finish(sum of set_hash_term over its indices); the facets of a simplex
// are its sum minus one term each.
inline std::uint64_t set_hash_term(std::uint32_t v) {
  std::uint64_t z = std::uint64_t{v} + 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}
inline std::uint64_t set_hash_finish(std::uint64_t sum) {
  sum = (sum ^ (sum >> 32)) * 0xD6E8FEB86659FD93ull;
  sum = (sum ^ (sum >> 32)) * 0xD6E8FEB86659FD93ull;
  return sum ^ (sum >> 32);
}

// Equality of two index tuples of length n, compared inline: std::equal becomes a
// memcmp call, which is slower for the 1-9 ids of a simplex or facet key.
inline bool same_indices(const std::uint32_t* a, const std::uint32_t* b, std::size_t n) {
  for (std::size_t i = 0; i < n; ++i) {
    if (a[i] != b[i]) return false;
  }
  return true;
}

}  // namespace spokemesh::detail
