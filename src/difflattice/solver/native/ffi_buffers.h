// buffer helpers shared by the FFI bindings (lattice.cc: 2-D and rz; volume.cc: 3-D)
#pragma once

#include <cstdint>
#include <cstring>

#include "xla/ffi/api/ffi.h"

namespace dl {

// the result buffer of an in-place argument, holding the argument's values (XLA may or may not
// have aliased them); nullptr for an empty (absent) argument
template <typename T>
T* out_from(xla::ffi::Result<xla::ffi::AnyBuffer>& r, const xla::ffi::AnyBuffer& in) {
  T* dst = reinterpret_cast<T*>(r->untyped_data());
  if (in.element_count() && dst != in.untyped_data()) std::memcpy(dst, in.untyped_data(), in.size_bytes());
  return in.element_count() ? dst : nullptr;
}

// every cell of an (n, 2) int32 list inside [0, n0) x [0, n1) (rows and columns; 3-D: planes and
// indices within a plane)
inline bool inside(const xla::ffi::AnyBuffer& cells, int64_t n0, int64_t n1) {
  const int32_t* c = reinterpret_cast<const int32_t*>(cells.untyped_data());
  const int64_t n = int64_t(cells.element_count() / 2);
  for (int64_t k = 0; k < n; ++k)
    if (c[2 * k] < 0 || c[2 * k] >= n0 || c[2 * k + 1] < 0 || c[2 * k + 1] >= n1) return false;
  return true;
}

}  // namespace dl
