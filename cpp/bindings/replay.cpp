// reflexarm._core.Controller.replay: see replay.hpp. Every array is checked for dtype, C order and shape
// here (a ValueError naming it otherwise); the loop itself is reflexarm::replayLog.
#include "replay.hpp"

#include <string>
#include <vector>

#include <nanobind/stl/string.h>

namespace reflexarm_bindings
{
  namespace
  {
    template<typename T>
    using Out = nb::ndarray<T, nb::c_contig, nb::device::cpu>;

    std::string shapeOf(size_t ndim, const int64_t * shape)
    {
      std::string s = "(";
      for (size_t i = 0; i < ndim; ++i)
        s += (i ? ", " : "") + std::to_string(shape[i]);
      return s + (ndim == 1 ? ",)" : ")");
    }

    void checkShape(const char * name, size_t ndim, const int64_t * shape, long rows, long cols)
    {
      const bool ok = cols == 0 ? (ndim == 1 && shape[0] == rows) : (ndim == 2 && shape[0] == rows && shape[1] == cols);
      if (!ok)
        throw reflexarm::ConfigError(std::string("replay: ") + name + " must have shape (" + std::to_string(rows)
                                     + (cols ? ", " + std::to_string(cols) + ")" : std::string(",)")) + "; got "
                                     + shapeOf(ndim, shape));
    }

    /// The data pointer of an output array of `rows` x `cols` (cols 0: one dimension), or nullptr for None.
    template<typename T>
    T * output(nb::handle h, const char * name, long rows, long cols, bool optional)
    {
      if (h.is_none())
      {
        if (optional)
          return nullptr;
        throw reflexarm::ConfigError(std::string("replay: the output ") + name + " is needed");
      }
      Out<T> a;
      if (!nb::try_cast(h, a, false))
        throw reflexarm::ConfigError(std::string("replay: the output ") + name
                                     + " must be a writable C-contiguous array of the right dtype");
      int64_t shape[2] = {0, 0};
      for (size_t i = 0; i < a.ndim() && i < 2; ++i)
        shape[i] = static_cast<int64_t>(a.shape(i));
      checkShape(name, a.ndim(), shape, rows, cols);
      return a.data();
    }

    template<typename A>
    void checkInput(const A & a, const char * name, long rows, long cols)
    {
      int64_t shape[2] = {0, 0};
      for (size_t i = 0; i < a.ndim() && i < 2; ++i)
        shape[i] = static_cast<int64_t>(a.shape(i));
      checkShape(name, a.ndim(), shape, rows, cols);
    }
  } // namespace

  nb::tuple replay(reflexarm::Controller & ctrl, reflexarm::Command & cmd, const ReplayCol & t, const ReplayRows & q,
                   const ReplayRows & dq, const ReplayRows & tau_m, nb::handle wrench, const ReplayCol & gravity,
                   nb::handle residual, nb::handle tau, nb::handle over, nb::handle collision, nb::handle mode,
                   nb::handle status, std::size_t max_faults, bool residual_only, int threads)
  {
    const long N = static_cast<long>(t.shape(0)), n = ctrl.nv();
    checkInput(q, "q", N, n);
    checkInput(dq, "dq", N, n);
    checkInput(tau_m, "tau_m", N, n);
    checkInput(gravity, "gravity", 3, 0);
    reflexarm::ReplayInputs in;
    in.rows = N;
    in.t = t.data();
    in.q = q.data();
    in.dq = dq.data();
    in.tau_m = tau_m.data();
    ReplayRows w;
    if (!wrench.is_none())
    {
      if (!nb::try_cast(wrench, w, false))
        throw reflexarm::ConfigError("replay: wrench must be a C-contiguous float64 array of shape (N, 6) or None");
      checkInput(w, "wrench", N, 6);
      in.wrench = w.data();
    }
    for (int i = 0; i < 3; ++i)
      in.gravity[i] = gravity.data()[i];
    reflexarm::ReplayOutputs out;
    out.residual = output<double>(residual, "residual", N, n, false);
    out.tau = output<double>(tau, "tau", N, n, true);
    out.over = output<std::uint8_t>(over, "over", N, n, true);
    out.collision = output<std::uint8_t>(collision, "collision", N, 0, true);
    out.mode = output<std::int8_t>(mode, "mode", N, 0, true);
    out.status = output<std::int32_t>(status, "status", N, 0, true);
    std::vector<reflexarm::ReplayFault> faults;
    // the GIL stays held: a Python thread stepping the same controller meanwhile would race with the replay (the
    // residual-only path's second thread computes the dynamics terms from the arrays only, without Python)
    reflexarm::ResidualReplayRun run;
    if (residual_only)
      run = reflexarm::replayResiduals(ctrl, cmd, in, out, faults, max_faults, threads);
    else
      run.rejected = reflexarm::replayLog(ctrl, cmd, in, out, faults, max_faults);
    nb::list texts;
    for (const auto & f : faults)
      texts.append(nb::make_tuple(f.row, f.text));
    return nb::make_tuple(run.rejected, texts, run.residual_only, std::string(run.reason));
  }
} // namespace reflexarm_bindings
