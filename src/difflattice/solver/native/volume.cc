// difflattice native CPU kernel for 3-D grids, called from JAX as an XLA FFI custom call
// (difflattice.solver.native.volume): `difflattice_volume` advances the 3-D leapfrog of
// difflattice.solver.stepper (the standard 7-point stencil; homogeneous air, or K and the three face
// conductance arrays of obstacles, cut cells and media; rigid and soft window sides, sponge, soft
// cells) over a block of steps per call, with the sources, probes, phasors and field statistics in
// the loop, in the JAX stepper's order. The x planes are the pipeline's rows (threads.h): each
// thread advances several steps per sweep over the planes, one plane apart, so a plane is loaded
// from memory once per block of steps. Compiled into the same library as lattice.cc (build.py).
#include <cstdint>
#include <cstring>

#include "ffi_buffers.h"
#include "volume.h"
#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

using dl::inside;
using dl::out_from;

template <typename T>
const T* full_or_null(const ffi::AnyBuffer& b, size_t n, bool* ok) {
  if (b.element_count() == 0) return nullptr;
  if (b.element_count() != n) *ok = false;
  return reinterpret_cast<const T*>(b.untyped_data());
}

// the PML layers' buffers of a difflattice_volume_layered call
struct VolumeLayerBind {
  ffi::AnyBuffer lp, lw, boxes;
  ffi::AnyBuffer fac[12];  // a_cell b_cell a_face b_face of x, then y, then z
  ffi::Result<ffi::AnyBuffer>*lp_o, *lw_o;
};

template <typename T>
ffi::Error volume_typed(ffi::AnyBuffer p, ffi::AnyBuffer pp, ffi::AnyBuffer K, ffi::AnyBuffer bx, ffi::AnyBuffer by,
                        ffi::AnyBuffer bz, ffi::AnyBuffer keep, ffi::AnyBuffer sponge, ffi::AnyBuffer src_cells,
                        ffi::AnyBuffer src_hard, ffi::AnyBuffer src_vals, ffi::AnyBuffer rec_cells,
                        ffi::AnyBuffer ph_cells, ffi::AnyBuffer ph_cos, ffi::AnyBuffer ph_sin, ffi::AnyBuffer ph_re,
                        ffi::AnyBuffer ph_im, ffi::AnyBuffer p_max, ffi::AnyBuffer p_sq, ffi::AnyBuffer arrival,
                        ffi::AnyBuffer n0, ffi::Result<ffi::AnyBuffer> p_o, ffi::Result<ffi::AnyBuffer> pp_o,
                        ffi::Result<ffi::AnyBuffer> rec_o, ffi::Result<ffi::AnyBuffer> ph_re_o,
                        ffi::Result<ffi::AnyBuffer> ph_im_o, ffi::Result<ffi::AnyBuffer> p_max_o,
                        ffi::Result<ffi::AnyBuffer> p_sq_o, ffi::Result<ffi::AnyBuffer> arrival_o, int64_t n_steps,
                        int64_t threads, int64_t levels, int64_t band, int64_t closed, int64_t stencil, double threshold,
                        VolumeLayerBind* lb) {
  auto dims = p.dimensions();
  if (dims.size() != 3) return ffi::Error::InvalidArgument("difflattice_volume: the field must be 3-D");
  const int64_t nx = dims[0], ny = dims[1], nz = dims[2], n = nx * ny * nz;
  dl::VolumeArgs<T> a{};
  a.nx = nx;
  a.ny = ny;
  a.nz = nz;
  a.n_steps = n_steps;
  a.n_threads = int(threads);
  a.levels = int(levels);
  a.band = band;
  a.iso = stencil == 1;
  bool ok = pp.element_count() == size_t(n);
  if (K.element_count() == 1) a.k = *reinterpret_cast<const T*>(K.untyped_data());
  else a.K = full_or_null<T>(K, size_t(n), &ok);
  a.bx = full_or_null<T>(bx, size_t((nx + 1) * ny * nz), &ok);
  a.by = full_or_null<T>(by, size_t(nx * (ny + 1) * nz), &ok);
  a.bz = full_or_null<T>(bz, size_t(nx * ny * (nz + 1)), &ok);
  ok = ok && (a.bx != nullptr) == (a.by != nullptr) && (a.bx != nullptr) == (a.bz != nullptr);
  ok = ok && (K.element_count() == 1 || a.K != nullptr) && !(a.iso && a.bx != nullptr);
  a.keep = full_or_null<T>(keep, size_t(n), &ok);
  a.sponge = full_or_null<T>(sponge, size_t(n), &ok);
  if (!ok)
    return ffi::Error::InvalidArgument(
        "difflattice_volume: K is not a scalar or a grid, or a face or cell array does not have its full shape, or "
        "face arrays with the isotropic stencil");
  const int64_t plane = ny * nz;
  if (!inside(src_cells, nx, plane) || !inside(rec_cells, nx, plane) || !inside(ph_cells, nx, plane))
    return ffi::Error::InvalidArgument("difflattice_volume: a source or sensor cell lies outside the grid");
  for (int s = 0; s < 6; ++s) a.closed[s] = (closed >> s) & 1;
  a.p = out_from<T>(p_o, p);
  a.pp = out_from<T>(pp_o, pp);
  dl::CellOps<T>& c = a.cells;
  c.ny = plane;
  c.src_cells = reinterpret_cast<const int32_t*>(src_cells.untyped_data());
  c.src_hard = reinterpret_cast<const int32_t*>(src_hard.untyped_data());
  c.src_vals = reinterpret_cast<const T*>(src_vals.untyped_data());
  c.n_src = int64_t(src_cells.element_count() / 2);
  c.rec_cells = reinterpret_cast<const int32_t*>(rec_cells.untyped_data());
  c.n_rec = int64_t(rec_cells.element_count() / 2);
  c.rec_out = reinterpret_cast<T*>(rec_o->untyped_data());
  c.ph_cells = reinterpret_cast<const int32_t*>(ph_cells.untyped_data());
  c.n_ph = int64_t(ph_cells.element_count() / 2);
  c.ph_cos = reinterpret_cast<const T*>(ph_cos.untyped_data());
  c.ph_sin = reinterpret_cast<const T*>(ph_sin.untyped_data());
  c.ph_re = out_from<T>(ph_re_o, ph_re);
  c.ph_im = out_from<T>(ph_im_o, ph_im);
  c.p_max = out_from<T>(p_max_o, p_max);
  c.p_sq = out_from<T>(p_sq_o, p_sq);
  c.arrival = out_from<int32_t>(arrival_o, arrival);
  c.threshold = T(threshold);
  c.n0 = *reinterpret_cast<const int32_t*>(n0.untyped_data());
  dl::VolumeLayers<T> la;
  if (lb) {
    if (a.iso || a.sponge)
      return ffi::Error::InvalidArgument("difflattice_volume_layered: no isotropic stencil or sponge with PML layers");
    la.n_boxes = int64_t(lb->boxes.element_count() / 6);
    la.boxes = reinterpret_cast<const int32_t*>(lb->boxes.untyped_data());
    int64_t np = 0, nf = 0;
    for (int64_t b = 0; b < la.n_boxes; ++b) {
      const int32_t* x = la.boxes + 6 * b;
      const int64_t X = x[1] - x[0], Y = x[3] - x[2], Z = x[5] - x[4];
      if (x[0] < 0 || x[1] > nx || x[2] < 0 || x[3] > ny || x[4] < 0 || x[5] > nz || X <= 0 || Y <= 0 || Z <= 0)
        return ffi::Error::InvalidArgument("difflattice_volume_layered: a layer box outside the grid");
      la.part_at.push_back(np);
      la.flux_at.push_back(nf);
      np += 3 * X * Y * Z;
      nf += (X + 1) * Y * Z + X * (Y + 1) * Z + X * Y * (Z + 1);
    }
    const int64_t len[3] = {nx, ny, nz};
    bool fine = int64_t(lb->lp.element_count()) == np && int64_t(lb->lw.element_count()) == nf;
    for (int ax = 0; ax < 3; ++ax) {
      const ffi::AnyBuffer* f = lb->fac + 4 * ax;
      fine = fine && int64_t(f[0].element_count()) == len[ax] && int64_t(f[1].element_count()) == len[ax] &&
             int64_t(f[2].element_count()) == len[ax] + 1 && int64_t(f[3].element_count()) == len[ax] + 1;
      la.a_cell[ax] = reinterpret_cast<const T*>(f[0].untyped_data());
      la.b_cell[ax] = reinterpret_cast<const T*>(f[1].untyped_data());
      la.a_face[ax] = reinterpret_cast<const T*>(f[2].untyped_data());
      la.b_face[ax] = reinterpret_cast<const T*>(f[3].untyped_data());
    }
    if (!fine) return ffi::Error::InvalidArgument("difflattice_volume_layered: layer fields or factors of the wrong size");
    la.parts = out_from<T>(*lb->lp_o, lb->lp);
    la.fluxes = out_from<T>(*lb->lw_o, lb->lw);
    a.layers = &la;
  }
  dl::volume<T>(a);
  return ffi::Error::Success();
}

ffi::Error volume_impl(ffi::AnyBuffer p, ffi::AnyBuffer pp, ffi::AnyBuffer K, ffi::AnyBuffer bx, ffi::AnyBuffer by,
                       ffi::AnyBuffer bz, ffi::AnyBuffer keep, ffi::AnyBuffer sponge, ffi::AnyBuffer src_cells,
                       ffi::AnyBuffer src_hard, ffi::AnyBuffer src_vals, ffi::AnyBuffer rec_cells,
                       ffi::AnyBuffer ph_cells, ffi::AnyBuffer ph_cos, ffi::AnyBuffer ph_sin, ffi::AnyBuffer ph_re,
                       ffi::AnyBuffer ph_im, ffi::AnyBuffer p_max, ffi::AnyBuffer p_sq, ffi::AnyBuffer arrival,
                       ffi::AnyBuffer n0, ffi::Result<ffi::AnyBuffer> p_o, ffi::Result<ffi::AnyBuffer> pp_o,
                       ffi::Result<ffi::AnyBuffer> rec_o, ffi::Result<ffi::AnyBuffer> ph_re_o,
                       ffi::Result<ffi::AnyBuffer> ph_im_o, ffi::Result<ffi::AnyBuffer> p_max_o,
                       ffi::Result<ffi::AnyBuffer> p_sq_o, ffi::Result<ffi::AnyBuffer> arrival_o, int64_t n_steps,
                       int64_t threads, int64_t levels, int64_t band, int64_t closed, int64_t stencil, double threshold) {
#define DL_ARGS                                                                                                   \
  p, pp, K, bx, by, bz, keep, sponge, src_cells, src_hard, src_vals, rec_cells, ph_cells, ph_cos, ph_sin, ph_re, \
      ph_im, p_max, p_sq, arrival, n0, p_o, pp_o, rec_o, ph_re_o, ph_im_o, p_max_o, p_sq_o, arrival_o, n_steps,  \
      threads, levels, band, closed, stencil, threshold, nullptr
  switch (p.element_type()) {
    case ffi::DataType::F32:
      return volume_typed<float>(DL_ARGS);
    case ffi::DataType::F64:
      return volume_typed<double>(DL_ARGS);
    default:
      return ffi::Error::InvalidArgument("difflattice_volume: float32 or float64 fields only");
  }
#undef DL_ARGS
}

// a volume call with PML layers: the volume's arguments, then lp lw boxes and the 12 factor profiles
ffi::Error volume_layered_impl(
    ffi::AnyBuffer p, ffi::AnyBuffer pp, ffi::AnyBuffer K, ffi::AnyBuffer bx, ffi::AnyBuffer by, ffi::AnyBuffer bz,
    ffi::AnyBuffer keep, ffi::AnyBuffer sponge, ffi::AnyBuffer src_cells, ffi::AnyBuffer src_hard,
    ffi::AnyBuffer src_vals, ffi::AnyBuffer rec_cells, ffi::AnyBuffer ph_cells, ffi::AnyBuffer ph_cos,
    ffi::AnyBuffer ph_sin, ffi::AnyBuffer ph_re, ffi::AnyBuffer ph_im, ffi::AnyBuffer p_max, ffi::AnyBuffer p_sq,
    ffi::AnyBuffer arrival, ffi::AnyBuffer n0, ffi::AnyBuffer lp, ffi::AnyBuffer lw, ffi::AnyBuffer boxes,
    ffi::AnyBuffer f0, ffi::AnyBuffer f1, ffi::AnyBuffer f2, ffi::AnyBuffer f3, ffi::AnyBuffer f4, ffi::AnyBuffer f5,
    ffi::AnyBuffer f6, ffi::AnyBuffer f7, ffi::AnyBuffer f8, ffi::AnyBuffer f9, ffi::AnyBuffer f10, ffi::AnyBuffer f11,
    ffi::Result<ffi::AnyBuffer> p_o, ffi::Result<ffi::AnyBuffer> pp_o, ffi::Result<ffi::AnyBuffer> rec_o,
    ffi::Result<ffi::AnyBuffer> ph_re_o, ffi::Result<ffi::AnyBuffer> ph_im_o, ffi::Result<ffi::AnyBuffer> p_max_o,
    ffi::Result<ffi::AnyBuffer> p_sq_o, ffi::Result<ffi::AnyBuffer> arrival_o, ffi::Result<ffi::AnyBuffer> lp_o,
    ffi::Result<ffi::AnyBuffer> lw_o, int64_t n_steps, int64_t threads, int64_t levels, int64_t band, int64_t closed,
    int64_t stencil, double threshold) {
  VolumeLayerBind lb{lp, lw, boxes, {f0, f1, f2, f3, f4, f5, f6, f7, f8, f9, f10, f11}, &lp_o, &lw_o};
#define DL_ARGS                                                                                                   \
  p, pp, K, bx, by, bz, keep, sponge, src_cells, src_hard, src_vals, rec_cells, ph_cells, ph_cos, ph_sin, ph_re, \
      ph_im, p_max, p_sq, arrival, n0, p_o, pp_o, rec_o, ph_re_o, ph_im_o, p_max_o, p_sq_o, arrival_o, n_steps,  \
      threads, levels, band, closed, stencil, threshold, &lb
  switch (p.element_type()) {
    case ffi::DataType::F32:
      return volume_typed<float>(DL_ARGS);
    case ffi::DataType::F64:
      return volume_typed<double>(DL_ARGS);
    default:
      return ffi::Error::InvalidArgument("difflattice_volume_layered: float32 or float64 fields only");
  }
#undef DL_ARGS
}

}  // namespace

#define DL_VBUFS_7 \
  .Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>()
#define DL_VRETS_4 .Ret<ffi::AnyBuffer>().Ret<ffi::AnyBuffer>().Ret<ffi::AnyBuffer>().Ret<ffi::AnyBuffer>()

// args: p pp K bx by bz keep | sponge src_cells src_hard src_vals rec_cells ph_cells ph_cos |
//       ph_sin ph_re ph_im p_max p_sq arrival n0
// rets: p pp rec ph_re ph_im p_max p_sq arrival
// attrs: closed = bit s set for a rigid window side s (x_lo x_hi y_lo y_hi z_lo z_hi) with unit faces;
//        stencil = 0 (standard 7-point) or 1 (isotropic 19-point, unit faces only)
XLA_FFI_DEFINE_HANDLER_SYMBOL(DifflatticeVolume, volume_impl,
                              ffi::Ffi::Bind() DL_VBUFS_7 DL_VBUFS_7 DL_VBUFS_7 DL_VRETS_4 DL_VRETS_4
                                  .Attr<int64_t>("n_steps")
                                  .Attr<int64_t>("threads")
                                  .Attr<int64_t>("levels")
                                  .Attr<int64_t>("band")
                                  .Attr<int64_t>("closed")
                                  .Attr<int64_t>("stencil")
                                  .Attr<double>("threshold"));

// args: the volume's 21 | lp lw boxes | ax_cell bx_cell ax_face bx_face, ay_..., az_... (12 profiles)
// rets: the volume's 8 | lp lw
XLA_FFI_DEFINE_HANDLER_SYMBOL(DifflatticeVolumeLayered, volume_layered_impl,
                              ffi::Ffi::Bind() DL_VBUFS_7 DL_VBUFS_7 DL_VBUFS_7 DL_VBUFS_7 DL_VBUFS_7
                                  .Arg<ffi::AnyBuffer>() DL_VRETS_4 DL_VRETS_4
                                  .Ret<ffi::AnyBuffer>()
                                  .Ret<ffi::AnyBuffer>()
                                  .Attr<int64_t>("n_steps")
                                  .Attr<int64_t>("threads")
                                  .Attr<int64_t>("levels")
                                  .Attr<int64_t>("band")
                                  .Attr<int64_t>("closed")
                                  .Attr<int64_t>("stencil")
                                  .Attr<double>("threshold"));
