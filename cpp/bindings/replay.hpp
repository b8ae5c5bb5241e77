// reflexarm._core.Controller.replay: a whole log through the controller in one call (bindings/replay.cpp).
#pragma once

#include <cstdint>

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include "reflexarm/replay.hpp"

namespace reflexarm_bindings
{
  namespace nb = nanobind;
  using ReplayCol = nb::ndarray<const double, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
  using ReplayRows = nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;

  /// Replays t (N,), q, dq, tau_m (N, n), wrench (N, 6) or None with the constant gravity (3,) into the
  /// caller's output arrays (residual (N, n) float64; tau (N, n) float64 or None; over (N, n) uint8; collision
  /// (N,) uint8; mode (N,) int8; status (N,) int32). residual_only: reflexarm::replayResiduals on `threads`
  /// threads (the GIL stays held: see replay.cpp), else
  /// reflexarm::replayLog. Returns (rejected rows, [(row, fault text) of the first max_faults], whether the
  /// residual-only path ran, why not).
  nb::tuple replay(reflexarm::Controller & ctrl, reflexarm::Command & cmd, const ReplayCol & t, const ReplayRows & q,
                   const ReplayRows & dq, const ReplayRows & tau_m, nb::handle wrench, const ReplayCol & gravity,
                   nb::handle residual, nb::handle tau, nb::handle over, nb::handle collision, nb::handle mode,
                   nb::handle status, std::size_t max_faults, bool residual_only, int threads);
} // namespace reflexarm_bindings
