// difflattice native CPU kernels, called from JAX as XLA FFI custom calls
// (difflattice.solver.native). Two time steppers of difflattice.solver.stepper, advanced over a
// block of steps per call:
//
// - `difflattice_leapfrog`: P(t+1) = 2 P(t) - P(t-1) + K L(q), L the flux stencil of
//   difflattice.lattice.operators, with the optional sponge, soft-cell factor (`keep`), q = c^2 P
//   (`q_scale`) and viscous (`eta`) terms; `combine = 2` runs the adjoint step instead.
// - `difflattice_layered`: the leapfrog with PML layers: the split-field form (face fluxes wx, wy;
//   pressure parts px, py) on the layer's boxes only, the leapfrog's arithmetic everywhere else.
//
// Both run the standard 5-point stencil, and the isotropic 9-point one (attribute `stencil` = 1)
// on uniform faces (air: the window's 0/1 masks and the rz metric; `row_iso`, `face_x_iso`).
//
// Both carry humid air's absorption (lattice.coefficients.AirRelaxation) when given its optional
// arguments: the operand adds eta (P - P(n-1)) + eps_O Q_O + eps_N Q_N, and after the sources
// Q_i = a_i Q_i + g_i (P(n+1) - P(n)) row by row, in place (a compile-time flag: the lossless
// instantiations have none of it).
//
// Both apply the sources, record probes, phasors and whole-field statistics inside the loop, in
// the order of the JAX stepper. Coefficient arrays are inputs of any layout that broadcasts to
// the grid (a scalar, one value per row, one vector for all rows, or a full array), so a lattice
// with metric coefficients (axisymmetric) runs the same code.
//
// Speed: temporal blocking (each thread advances several steps per sweep over the rows, one row
// apart) and a pipeline of threads (thread t takes the steps after thread t - 1's, one row
// behind it), so rows are loaded from memory once per block of steps and all cores work without
// a barrier per step. Results agree with the JAX reference to rounding (the stencil sums the
// neighbours first where faces have unit conductance; XLA contracts a * b + c into FMAs, so this
// file is compiled with -ffp-contract=fast as well).
//
// Files: threads.h (worker pool, pipeline), cells.h (coefficient layouts, cell operations),
// stencil.h (row kernels and plans), layers.h (PML layer boxes), leapfrog.h (the stepping loop),
// adjoint.h (the lattice adjoint's chunk); this file binds them to XLA's FFI.
#include <cstdint>
#include <cstring>
#include <optional>
#include <string>
#include <vector>

#include "adjoint.h"
#include "ffi_buffers.h"
#include "leapfrog.h"
#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

// ------------------------------------------------------------------------------------------------
// FFI binding

namespace {

using dl::inside;
using dl::out_from;

const char* kOutside = "difflattice: a source or sensor cell lies outside the grid";

template <typename T>
void bind_cells(dl::CellOps<T>& c, int64_t ny, const ffi::AnyBuffer& src_cells, const ffi::AnyBuffer& src_hard,
                const ffi::AnyBuffer& src_vals, const ffi::AnyBuffer& rec_cells, ffi::Result<ffi::AnyBuffer>& rec,
                const ffi::AnyBuffer& ph_cells, const ffi::AnyBuffer& ph_cos, const ffi::AnyBuffer& ph_sin,
                T* ph_re, T* ph_im, T* p_max, T* p_sq, int32_t* arrival, const ffi::AnyBuffer& n0,
                double threshold) {
  c.ny = ny;
  c.src_cells = reinterpret_cast<const int32_t*>(src_cells.untyped_data());
  c.src_hard = reinterpret_cast<const int32_t*>(src_hard.untyped_data());
  c.src_vals = reinterpret_cast<const T*>(src_vals.untyped_data());
  c.n_src = int64_t(src_cells.element_count() / 2);
  c.rec_cells = reinterpret_cast<const int32_t*>(rec_cells.untyped_data());
  c.n_rec = int64_t(rec_cells.element_count() / 2);
  c.rec_out = reinterpret_cast<T*>(rec->untyped_data());
  c.ph_cells = reinterpret_cast<const int32_t*>(ph_cells.untyped_data());
  c.n_ph = int64_t(ph_cells.element_count() / 2);
  c.ph_cos = reinterpret_cast<const T*>(ph_cos.untyped_data());
  c.ph_sin = reinterpret_cast<const T*>(ph_sin.untyped_data());
  c.ph_re = ph_re;
  c.ph_im = ph_im;
  c.p_max = p_max;
  c.p_sq = p_sq;
  c.arrival = arrival;
  c.threshold = T(threshold);
  c.n0 = *reinterpret_cast<const int32_t*>(n0.untyped_data());
}

// air absorption's inputs (both kernels), optional arguments and results after the others (a
// lossless call passes none of them: the call of old): the memory fields Q_O, Q_N and their 7
// coefficients (eta, eps_O, eps_N, a_O, a_N, g_O, g_N); false: some given, not all, or
// inconsistent sizes or types
using Opt = std::optional<ffi::AnyBuffer>;
using OptRet = std::optional<ffi::Result<ffi::AnyBuffer>>;

template <typename T, typename Args>
bool bind_relax(Args& a, int64_t n_cells, ffi::DataType type, const Opt& rq0_, const Opt& rq1_, const Opt& relax_,
                OptRet& rq0_o, OptRet& rq1_o) {
  if (!rq0_ && !rq1_ && !relax_ && !rq0_o && !rq1_o) return true;  // lossless: the call of old
  if (!rq0_ || !rq1_ || !relax_ || !rq0_o || !rq1_o) return false;
  const ffi::AnyBuffer &rq0 = *rq0_, &rq1 = *rq1_, &relax = *relax_;
  if (int64_t(rq0.element_count()) != n_cells || int64_t(rq1.element_count()) != n_cells ||
      relax.element_count() != 7 || relax.element_type() != type || rq0.element_type() != type ||
      rq1.element_type() != type)
    return false;
  a.rq[0] = out_from<T>(*rq0_o, rq0);
  a.rq[1] = out_from<T>(*rq1_o, rq1);
  const T* r = reinterpret_cast<const T*>(relax.untyped_data());
  a.r_eta = r[0];
  a.r_eps[0] = r[1];
  a.r_eps[1] = r[2];
  a.r_a[0] = r[3];
  a.r_a[1] = r[4];
  a.r_g[0] = r[5];
  a.r_g[1] = r[6];
  return true;
}

const char* kRelax = "air absorption needs two memory fields of the grid's shape and 7 coefficients";

// the extra buffers of a call with PML layers (difflattice_layered): the boxes' packed fields (parts
// px, py of each box; faces wx, wy of each box; the ring correction of each box on the r_hi
// rings), the boxes (n, 4: r0 r1 c0 c1), the PML factors and the ring correction's factors
struct LayerBind {
  ffi::AnyBuffer lp, lw, lc, boxes, axc, bxc, axf, bxf, ayc, byc, ayf, byf, rad_decay, rad_drive;
  ffi::Result<ffi::AnyBuffer>*lp_o, *lw_o, *lc_o;
};

template <typename T>
const char* bind_layers(dl::LayerArgs<T>& la, LayerBind& lb, const dl::LeapfrogArgs<T>& a) {
  const int64_t nx = a.nx, ny = a.ny;
  bool ok = true;
  la.axc = dl::make_coef<T>(lb.axc, nx, ny, &ok);
  la.bxc = dl::make_coef<T>(lb.bxc, nx, ny, &ok);
  la.axf = dl::make_coef<T>(lb.axf, nx + 1, ny, &ok);
  la.bxf = dl::make_coef<T>(lb.bxf, nx + 1, ny, &ok);
  la.ayc = dl::make_coef<T>(lb.ayc, nx, ny, &ok);
  la.byc = dl::make_coef<T>(lb.byc, nx, ny, &ok);
  la.ayf = dl::make_coef<T>(lb.ayf, nx, ny + 1, &ok);
  la.byf = dl::make_coef<T>(lb.byf, nx, ny + 1, &ok);
  auto row_layout = [](const dl::Coef<T>& c) { return !c.present() || c.mode == dl::kScalar || c.mode == dl::kPerRow; };
  auto col_layout = [](const dl::Coef<T>& c) { return !c.present() || c.mode == dl::kPerCol; };
  ok = ok && row_layout(la.axc) && row_layout(la.bxc) && row_layout(la.axf) && row_layout(la.bxf) &&
       col_layout(la.ayc) && col_layout(la.byc) && col_layout(la.ayf) && col_layout(la.byf);
  if (!ok) return "PML factors of an unsupported layout";
  la.iso_faces = a.iso && ((a.bx.present() && !a.bx.in_register()) ||
                            (a.by.present() && a.by.mode != dl::kScalar && a.by.mode != dl::kPerCol));
  if (la.iso_faces) dl::materialise(a.by, nx, ny + 1, la.by_full);
  la.w = int64_t(lb.rad_decay.element_count());
  if (la.w > ny || int64_t(lb.rad_drive.element_count()) != la.w) return "radial PML arrays of inconsistent sizes";
  la.rad_decay = reinterpret_cast<const T*>(lb.rad_decay.untyped_data());
  la.rad_drive = reinterpret_cast<const T*>(lb.rad_drive.untyped_data());
  T* lp = out_from<T>(*lb.lp_o, lb.lp);
  T* lw = out_from<T>(*lb.lw_o, lb.lw);
  T* lc = out_from<T>(*lb.lc_o, lb.lc);
  const int32_t* bx = reinterpret_cast<const int32_t*>(lb.boxes.untyped_data());
  const int64_t n_boxes = int64_t(lb.boxes.element_count() / 4);
  int64_t op = 0, ow = 0, oc = 0;
  la.of_row.assign(nx, {});
  std::vector<int64_t> covered(nx, 0);
  for (int64_t k = 0; k < n_boxes; ++k) {
    dl::LayerBox<T> b{};
    b.r0 = bx[4 * k];
    b.r1 = bx[4 * k + 1];
    b.c0 = bx[4 * k + 2];
    b.c1 = bx[4 * k + 3];
    if (b.r0 < 0 || b.r1 > nx || b.r0 >= b.r1 || b.c0 < 0 || b.c1 > ny || b.c0 >= b.c1) return "a layer box outside the grid";
    const int64_t nr = b.r1 - b.r0, nc = b.c1 - b.c0;
    b.px = lp + op;
    b.py = lp + op + nr * nc;
    op += 2 * nr * nc;
    b.wx = lw + ow;
    b.wy = lw + ow + (nr + 1) * nc;
    ow += (nr + 1) * nc + nr * (nc + 1);
    if (la.w && b.c1 == ny) {
      if (nc < la.w) return "a box on the r_hi rings narrower than the layer";
      b.cr = lc + oc;
      oc += nr * la.w;
    }
    for (int64_t i = b.r0; i < b.r1; ++i) {
      la.of_row[i].push_back(int(k));
      covered[i] += nc;
    }
    la.boxes.push_back(b);
  }
  if (op != int64_t(lb.lp.element_count()) || ow != int64_t(lb.lw.element_count()) || oc != int64_t(lb.lc.element_count()))
    return "layer fields whose sizes do not match the boxes";
  la.whole_row.assign(nx, 0);
  for (int64_t i = 0; i < nx; ++i) {
    if (covered[i] > ny) return "overlapping layer boxes";
    la.whole_row[i] = covered[i] == ny;
  }
  return nullptr;
}

template <typename T>
ffi::Error leapfrog_typed(ffi::AnyBuffer p, ffi::AnyBuffer pp, ffi::AnyBuffer K, ffi::AnyBuffer bx, ffi::AnyBuffer by,
                          ffi::AnyBuffer qs, ffi::AnyBuffer keep, ffi::AnyBuffer sponge, ffi::AnyBuffer my_lo,
                          ffi::AnyBuffer my_hi, ffi::AnyBuffer src_cells,
                          ffi::AnyBuffer src_hard, ffi::AnyBuffer src_vals, ffi::AnyBuffer rec_cells,
                          ffi::AnyBuffer zero_cells, ffi::AnyBuffer ph_cells, ffi::AnyBuffer ph_cos,
                          ffi::AnyBuffer ph_sin, ffi::AnyBuffer ph_re, ffi::AnyBuffer ph_im, ffi::AnyBuffer p_max,
                          ffi::AnyBuffer p_sq, ffi::AnyBuffer arrival, ffi::AnyBuffer n0,
                          ffi::Result<ffi::AnyBuffer> p_o, ffi::Result<ffi::AnyBuffer> pp_o,
                          ffi::Result<ffi::AnyBuffer> rec_o, ffi::Result<ffi::AnyBuffer> ph_re_o,
                          ffi::Result<ffi::AnyBuffer> ph_im_o, ffi::Result<ffi::AnyBuffer> p_max_o,
                          ffi::Result<ffi::AnyBuffer> p_sq_o, ffi::Result<ffi::AnyBuffer> arrival_o,
                          Opt rq0, Opt rq1, Opt relax, OptRet rq0_o, OptRet rq1_o,
                          int64_t n_steps, int64_t threads, int64_t levels, int64_t bands, int64_t combine,
                          int64_t stencil, double eta, double threshold, LayerBind* lb) {
  auto dims = p.dimensions();
  if (dims.size() != 2) return ffi::Error::InvalidArgument("difflattice_leapfrog: the field must be 2-D");
  const int64_t nx = dims[0], ny = dims[1];
  dl::LeapfrogArgs<T> a{};
  a.nx = nx;
  a.ny = ny;
  a.n_steps = n_steps;
  a.n_threads = int(threads);
  a.levels = int(levels);
  a.bands = bands != 0;
  a.combine = int(combine);
  a.iso = stencil == 1;
  bool ok = true;
  a.K = dl::make_coef<T>(K, nx, ny, &ok);
  a.bx = dl::make_coef<T>(bx, nx + 1, ny, &ok);
  a.by = dl::make_coef<T>(by, nx, ny + 1, &ok);
  a.qs = dl::make_coef<T>(qs, nx, ny, &ok);
  a.keep = dl::make_coef<T>(keep, nx, ny, &ok);
  a.sponge = dl::make_coef<T>(sponge, nx, ny, &ok);
  a.my_lo = dl::make_coef<T>(my_lo, nx, ny, &ok);
  a.my_hi = dl::make_coef<T>(my_hi, nx, ny, &ok);
  ok = ok && (a.my_lo.present() == a.my_hi.present());
  if (!ok || !a.K.present())
    return ffi::Error::InvalidArgument("difflattice_leapfrog: a coefficient array does not broadcast to the grid");
  if (!inside(src_cells, nx, ny) || !inside(rec_cells, nx, ny) || !inside(zero_cells, nx, ny) ||
      !inside(ph_cells, nx, ny))
    return ffi::Error::InvalidArgument(kOutside);
  a.p = out_from<T>(p_o, p);
  a.pp = out_from<T>(pp_o, pp);
  a.eta = eta;
  bind_cells<T>(a.cells, ny, src_cells, src_hard, src_vals, rec_cells, rec_o, ph_cells, ph_cos, ph_sin,
                out_from<T>(ph_re_o, ph_re), out_from<T>(ph_im_o, ph_im), out_from<T>(p_max_o, p_max),
                out_from<T>(p_sq_o, p_sq), out_from<int32_t>(arrival_o, arrival), n0, threshold);
  a.cells.zero_cells = reinterpret_cast<const int32_t*>(zero_cells.untyped_data());
  a.cells.n_zero = int64_t(zero_cells.element_count() / 2);
  if (!bind_relax<T>(a, nx * ny, p.element_type(), rq0, rq1, relax, rq0_o, rq1_o))
    return ffi::Error::InvalidArgument(std::string("difflattice_leapfrog: ") + kRelax);
  if (a.rq[0] && combine == dl::kAdj)
    return ffi::Error::InvalidArgument("difflattice_leapfrog: the adjoint mode has no air absorption");
  dl::LayerArgs<T> la;
  if (lb) {
    if (combine == dl::kAdj) return ffi::Error::InvalidArgument("difflattice_layered: the adjoint mode has no PML layers");
    if (const char* err = bind_layers<T>(la, *lb, a)) return ffi::Error::InvalidArgument(std::string("difflattice_layered: ") + err);
    a.layers = &la;
  }
  if (!dl::leapfrog<T>(a)) return ffi::Error::InvalidArgument("difflattice_leapfrog: unsupported coefficient layout");
  return ffi::Error::Success();
}

ffi::Error leapfrog_impl(ffi::AnyBuffer p, ffi::AnyBuffer pp, ffi::AnyBuffer K, ffi::AnyBuffer bx, ffi::AnyBuffer by,
                         ffi::AnyBuffer qs, ffi::AnyBuffer keep, ffi::AnyBuffer sponge, ffi::AnyBuffer my_lo,
                         ffi::AnyBuffer my_hi, ffi::AnyBuffer src_cells,
                         ffi::AnyBuffer src_hard, ffi::AnyBuffer src_vals, ffi::AnyBuffer rec_cells,
                         ffi::AnyBuffer zero_cells, ffi::AnyBuffer ph_cells, ffi::AnyBuffer ph_cos,
                         ffi::AnyBuffer ph_sin, ffi::AnyBuffer ph_re, ffi::AnyBuffer ph_im, ffi::AnyBuffer p_max,
                         ffi::AnyBuffer p_sq, ffi::AnyBuffer arrival, ffi::AnyBuffer n0,
                         ffi::Result<ffi::AnyBuffer> p_o, ffi::Result<ffi::AnyBuffer> pp_o,
                         ffi::Result<ffi::AnyBuffer> rec_o, ffi::Result<ffi::AnyBuffer> ph_re_o,
                         ffi::Result<ffi::AnyBuffer> ph_im_o, ffi::Result<ffi::AnyBuffer> p_max_o,
                         ffi::Result<ffi::AnyBuffer> p_sq_o, ffi::Result<ffi::AnyBuffer> arrival_o,
                         Opt rq0, Opt rq1, Opt relax, OptRet rq0_o, OptRet rq1_o, int64_t n_steps, int64_t threads, int64_t levels, int64_t bands, int64_t combine,
                         int64_t stencil, double eta, double threshold) {
#define DL_ARGS                                                                                                 \
  p, pp, K, bx, by, qs, keep, sponge, my_lo, my_hi, src_cells, src_hard, src_vals, rec_cells, zero_cells, ph_cells, ph_cos, \
      ph_sin, ph_re, ph_im, p_max, p_sq, arrival, n0, p_o, pp_o, rec_o, ph_re_o, ph_im_o, p_max_o, p_sq_o,      \
      arrival_o, rq0, rq1, relax, rq0_o, rq1_o, n_steps, threads, levels, bands, combine, stencil, eta, threshold, \
      nullptr
  switch (p.element_type()) {
    case ffi::DataType::F32:
      return leapfrog_typed<float>(DL_ARGS);
    case ffi::DataType::F64:
      return leapfrog_typed<double>(DL_ARGS);
    default:
      return ffi::Error::InvalidArgument("difflattice_leapfrog: float32 or float64 fields only");
  }
#undef DL_ARGS
}

// a leapfrog call with PML layers: the leapfrog's arguments, then the layers' (`LayerBind`)
ffi::Error layered_impl(ffi::AnyBuffer p, ffi::AnyBuffer pp, ffi::AnyBuffer K, ffi::AnyBuffer bx, ffi::AnyBuffer by,
                        ffi::AnyBuffer qs, ffi::AnyBuffer keep, ffi::AnyBuffer sponge, ffi::AnyBuffer my_lo,
                        ffi::AnyBuffer my_hi, ffi::AnyBuffer src_cells, ffi::AnyBuffer src_hard,
                        ffi::AnyBuffer src_vals, ffi::AnyBuffer rec_cells, ffi::AnyBuffer zero_cells,
                        ffi::AnyBuffer ph_cells, ffi::AnyBuffer ph_cos, ffi::AnyBuffer ph_sin, ffi::AnyBuffer ph_re,
                        ffi::AnyBuffer ph_im, ffi::AnyBuffer p_max, ffi::AnyBuffer p_sq, ffi::AnyBuffer arrival,
                        ffi::AnyBuffer n0, ffi::AnyBuffer lp, ffi::AnyBuffer lw, ffi::AnyBuffer lc,
                        ffi::AnyBuffer boxes, ffi::AnyBuffer axc, ffi::AnyBuffer bxc, ffi::AnyBuffer axf,
                        ffi::AnyBuffer bxf, ffi::AnyBuffer ayc, ffi::AnyBuffer byc, ffi::AnyBuffer ayf,
                        ffi::AnyBuffer byf, ffi::AnyBuffer rad_decay, ffi::AnyBuffer rad_drive,
                        ffi::Result<ffi::AnyBuffer> p_o, ffi::Result<ffi::AnyBuffer> pp_o,
                        ffi::Result<ffi::AnyBuffer> rec_o, ffi::Result<ffi::AnyBuffer> ph_re_o,
                        ffi::Result<ffi::AnyBuffer> ph_im_o, ffi::Result<ffi::AnyBuffer> p_max_o,
                        ffi::Result<ffi::AnyBuffer> p_sq_o, ffi::Result<ffi::AnyBuffer> arrival_o,
                        ffi::Result<ffi::AnyBuffer> lp_o, ffi::Result<ffi::AnyBuffer> lw_o,
                        ffi::Result<ffi::AnyBuffer> lc_o, Opt rq0, Opt rq1, Opt relax, OptRet rq0_o, OptRet rq1_o,
                        int64_t n_steps, int64_t threads, int64_t levels, int64_t bands, int64_t combine,
                        int64_t stencil, double eta, double threshold) {
  LayerBind lb{lp, lw, lc, boxes, axc, bxc, axf, bxf, ayc, byc, ayf, byf, rad_decay, rad_drive, &lp_o, &lw_o, &lc_o};
  if (sponge.element_count() || zero_cells.element_count())
    return ffi::Error::InvalidArgument("difflattice_layered: no sponge or zeroed cells with PML layers");
#define DL_ARGS                                                                                                 \
  p, pp, K, bx, by, qs, keep, sponge, my_lo, my_hi, src_cells, src_hard, src_vals, rec_cells, zero_cells, ph_cells, ph_cos, \
      ph_sin, ph_re, ph_im, p_max, p_sq, arrival, n0, p_o, pp_o, rec_o, ph_re_o, ph_im_o, p_max_o, p_sq_o,      \
      arrival_o, rq0, rq1, relax, rq0_o, rq1_o, n_steps, threads, levels, bands, combine, stencil, eta, threshold, &lb
  switch (p.element_type()) {
    case ffi::DataType::F32:
      return leapfrog_typed<float>(DL_ARGS);
    case ffi::DataType::F64:
      return leapfrog_typed<double>(DL_ARGS);
    default:
      return ffi::Error::InvalidArgument("difflattice_layered: float32 or float64 fields only");
  }
#undef DL_ARGS
}

template <typename T>
ffi::Error adjoint_chunk_typed(ffi::AnyBuffer p_end, ffi::AnyBuffer pp_end, ffi::AnyBuffer x, ffi::AnyBuffer h,
                               ffi::AnyBuffer K, ffi::AnyBuffer bx, ffi::AnyBuffer by, ffi::AnyBuffer ml,
                               ffi::AnyBuffer mh, ffi::AnyBuffer vol, ffi::AnyBuffer area, ffi::AnyBuffer src_cells,
                               ffi::AnyBuffer src_hard, ffi::AnyBuffer src_vals, ffi::AnyBuffer inj_cells,
                               ffi::AnyBuffer inj_vals, ffi::AnyBuffer rec_cells, ffi::AnyBuffer zero_cells,
                               ffi::AnyBuffer dK, ffi::AnyBuffer dbx, ffi::AnyBuffer dby,
                               ffi::Result<ffi::AnyBuffer> x_o, ffi::Result<ffi::AnyBuffer> h_o,
                               ffi::Result<ffi::AnyBuffer> rec_o, ffi::Result<ffi::AnyBuffer> dK_o,
                               ffi::Result<ffi::AnyBuffer> dbx_o, ffi::Result<ffi::AnyBuffer> dby_o, int64_t n_steps,
                               int64_t threads, int64_t levels) {
  auto dims = x.dimensions();
  if (dims.size() != 2) return ffi::Error::InvalidArgument("difflattice_adjoint_chunk: the field must be 2-D");
  const int64_t nx = dims[0], ny = dims[1];
  const char* bad = "difflattice_adjoint_chunk: an argument has the wrong size";
  if (p_end.element_count() != size_t(nx * ny) || pp_end.element_count() != size_t(nx * ny) ||
      h.element_count() != size_t(nx * ny) || bx.element_count() != size_t((nx + 1) * ny) ||
      by.element_count() != size_t(nx * (ny + 1)) ||
      (ml.element_count() &&  // the ring metric, or none (a plane grid: four empty arrays)
       (ml.element_count() != size_t(ny) || mh.element_count() != size_t(ny) || vol.element_count() != size_t(ny) ||
        area.element_count() != size_t(ny + 1))) ||
      (dK.element_count() && dK.element_count() != size_t(nx * ny)) ||
      (dbx.element_count() && dbx.element_count() != size_t((nx + 1) * ny)) ||
      (dby.element_count() && dby.element_count() != size_t(nx * (ny + 1))) || n_steps < 1 ||
      src_vals.element_count() != size_t((n_steps + 2) * (src_cells.element_count() / 2)))
    return ffi::Error::InvalidArgument(bad);
  if (!inside(src_cells, nx, ny) || !inside(inj_cells, nx, ny) || !inside(rec_cells, nx, ny) ||
      !inside(zero_cells, nx, ny))
    return ffi::Error::InvalidArgument(kOutside);
  dl::AdjointChunkArgs<T> a{};
  a.nx = nx;
  a.ny = ny;
  a.len = n_steps;
  a.n_threads = int(threads);
  a.levels = int(levels);
  bool ok = true;
  a.K = dl::make_coef<T>(K, nx, ny, &ok);
  if (!ok || !a.K.present())
    return ffi::Error::InvalidArgument("difflattice_adjoint_chunk: K does not broadcast to the grid");
  auto ptr = [](const ffi::AnyBuffer& b) { return reinterpret_cast<const T*>(b.untyped_data()); };
  a.p_end = ptr(p_end);
  a.pp_end = ptr(pp_end);
  a.bx = ptr(bx);
  a.by = ptr(by);
  if (ml.element_count()) {
    a.ml = ptr(ml);
    a.mh = ptr(mh);
    a.vol = ptr(vol);
    a.area = ptr(area);
  }
  a.x = out_from<T>(x_o, x);
  a.h = out_from<T>(h_o, h);
  a.dK = out_from<T>(dK_o, dK);
  a.dbx = out_from<T>(dbx_o, dbx);
  a.dby = out_from<T>(dby_o, dby);
  a.src_cells = reinterpret_cast<const int32_t*>(src_cells.untyped_data());
  a.src_hard = reinterpret_cast<const int32_t*>(src_hard.untyped_data());
  a.src_vals = ptr(src_vals);
  a.n_src = int64_t(src_cells.element_count() / 2);
  std::vector<int32_t> soft(inj_cells.element_count() / 2, 0);
  a.adj.ny = ny;
  a.adj.src_cells = reinterpret_cast<const int32_t*>(inj_cells.untyped_data());
  a.adj.src_hard = soft.data();
  a.adj.src_vals = ptr(inj_vals);
  a.adj.n_src = int64_t(soft.size());
  a.adj.rec_cells = reinterpret_cast<const int32_t*>(rec_cells.untyped_data());
  a.adj.n_rec = int64_t(rec_cells.element_count() / 2);
  a.adj.rec_out = reinterpret_cast<T*>(rec_o->untyped_data());
  a.adj.zero_cells = reinterpret_cast<const int32_t*>(zero_cells.untyped_data());
  a.adj.n_zero = int64_t(zero_cells.element_count() / 2);
  dl::adjoint_chunk<T>(a);
  return ffi::Error::Success();
}

ffi::Error adjoint_chunk_impl(ffi::AnyBuffer p_end, ffi::AnyBuffer pp_end, ffi::AnyBuffer x, ffi::AnyBuffer h,
                              ffi::AnyBuffer K, ffi::AnyBuffer bx, ffi::AnyBuffer by, ffi::AnyBuffer ml,
                              ffi::AnyBuffer mh, ffi::AnyBuffer vol, ffi::AnyBuffer area, ffi::AnyBuffer src_cells,
                              ffi::AnyBuffer src_hard, ffi::AnyBuffer src_vals, ffi::AnyBuffer inj_cells,
                              ffi::AnyBuffer inj_vals, ffi::AnyBuffer rec_cells, ffi::AnyBuffer zero_cells,
                              ffi::AnyBuffer dK, ffi::AnyBuffer dbx, ffi::AnyBuffer dby,
                              ffi::Result<ffi::AnyBuffer> x_o, ffi::Result<ffi::AnyBuffer> h_o,
                              ffi::Result<ffi::AnyBuffer> rec_o, ffi::Result<ffi::AnyBuffer> dK_o,
                              ffi::Result<ffi::AnyBuffer> dbx_o, ffi::Result<ffi::AnyBuffer> dby_o, int64_t n_steps,
                              int64_t threads, int64_t levels) {
#define DL_ARGS                                                                                                   \
  p_end, pp_end, x, h, K, bx, by, ml, mh, vol, area, src_cells, src_hard, src_vals, inj_cells, inj_vals,     \
      rec_cells, zero_cells, dK, dbx, dby, x_o, h_o, rec_o, dK_o, dbx_o, dby_o, n_steps, threads, levels
  switch (x.element_type()) {
    case ffi::DataType::F32:
      return adjoint_chunk_typed<float>(DL_ARGS);
    case ffi::DataType::F64:
      return adjoint_chunk_typed<double>(DL_ARGS);
    default:
      return ffi::Error::InvalidArgument("difflattice_adjoint_chunk: float32 or float64 fields only");
  }
#undef DL_ARGS
}

}  // namespace

#define DL_BUFS_8 \
  .Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>()
#define DL_RETS_4 .Ret<ffi::AnyBuffer>().Ret<ffi::AnyBuffer>().Ret<ffi::AnyBuffer>().Ret<ffi::AnyBuffer>()

// args: p pp K bx by qs keep sponge | my_lo my_hi src_cells src_hard src_vals rec_cells zero_cells
//       ph_cells | ph_cos ph_sin ph_re ph_im p_max p_sq arrival n0 | optional: rq0 rq1 relax (air
//       absorption: the memory fields Q_O, Q_N and their 7 coefficients; absent: lossless)
// rets: p pp rec ph_re ph_im p_max p_sq arrival | optional: rq0 rq1
#define DL_RELAX                                                                                             \
  .OptionalArg<ffi::AnyBuffer>().OptionalArg<ffi::AnyBuffer>().OptionalArg<ffi::AnyBuffer>().OptionalRet<ffi::AnyBuffer>() \
      .OptionalRet<ffi::AnyBuffer>()
XLA_FFI_DEFINE_HANDLER_SYMBOL(DifflatticeLeapfrog, leapfrog_impl,
                              ffi::Ffi::Bind() DL_BUFS_8 DL_BUFS_8.Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>() DL_RETS_4 DL_RETS_4 DL_RELAX.Attr<int64_t>("n_steps")
                                  .Attr<int64_t>("threads")
                                  .Attr<int64_t>("levels")
                                  .Attr<int64_t>("bands")
                                  .Attr<int64_t>("combine")
                                  .Attr<int64_t>("stencil")
                                  .Attr<double>("eta")
                                  .Attr<double>("threshold"));

// args: the leapfrog's 24 | lp lw lc boxes axc bxc axf bxf | ayc byc ayf byf rad_decay rad_drive |
//       optional: rq0 rq1 relax
// rets: the leapfrog's 8 | lp lw lc | optional: rq0 rq1
XLA_FFI_DEFINE_HANDLER_SYMBOL(DifflatticeLayered, layered_impl,
                              ffi::Ffi::Bind() DL_BUFS_8 DL_BUFS_8 DL_BUFS_8 DL_BUFS_8.Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>() DL_RETS_4 DL_RETS_4.Ret<ffi::AnyBuffer>()
                                  .Ret<ffi::AnyBuffer>()
                                  .Ret<ffi::AnyBuffer>() DL_RELAX.Attr<int64_t>("n_steps")
                                  .Attr<int64_t>("threads")
                                  .Attr<int64_t>("levels")
                                  .Attr<int64_t>("bands")
                                  .Attr<int64_t>("combine")
                                  .Attr<int64_t>("stencil")
                                  .Attr<double>("eta")
                                  .Attr<double>("threshold"));

// args: p_end pp_end x h K bx by ml | mh vol area src_cells src_hard src_vals inj_cells inj_vals |
//       rec_cells zero_cells dK dbx dby
// rets: x h rec dK dbx dby
XLA_FFI_DEFINE_HANDLER_SYMBOL(DifflatticeAdjointChunk, adjoint_chunk_impl,
                              ffi::Ffi::Bind() DL_BUFS_8 DL_BUFS_8.Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>() DL_RETS_4.Ret<ffi::AnyBuffer>()
                                  .Ret<ffi::AnyBuffer>()
                                  .Attr<int64_t>("n_steps")
                                  .Attr<int64_t>("threads")
                                  .Attr<int64_t>("levels"));
