// reflexarm._closed_loop.RunStatistics: reflexarm::RunStatistics from Python, folded from the compiled loop's
// block buffers after each block (reflexarm.sim.compiled_stream); read back as numpy copies.
#include <cstdint>
#include <string>
#include <vector>

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include "reflexarm/params.hpp"
#include "reflexarm/run_statistics.hpp"

namespace nb = nanobind;
using namespace nb::literals;

namespace
{
  template<typename T>
  using In = nb::ndarray<const T, nb::c_contig, nb::device::cpu>;
  using Stats = reflexarm::RunStatistics;

  /// The data of an array of at least `rows` rows of `cols` columns (cols 0: one dimension).
  template<typename T>
  const T * rowsAtLeast(const In<T> & a, long rows, long cols, const char * name)
  {
    const bool ok = cols == 0 ? (a.ndim() == 1 && static_cast<long>(a.shape(0)) >= rows)
                              : (a.ndim() == 2 && static_cast<long>(a.shape(0)) >= rows
                                 && static_cast<long>(a.shape(1)) == cols);
    if (!ok)
      throw reflexarm::ConfigError(std::string("RunStatistics.add_rows: ") + name + " must have at least "
                                   + std::to_string(rows) + " rows" + (cols ? " of " + std::to_string(cols) : ""));
    return a.data();
  }

  template<typename T>
  nb::ndarray<nb::numpy, T> copyOf(const std::vector<T> & v, size_t rows = 0, size_t cols = 0)
  {
    auto * data = new std::vector<T>(v);
    nb::capsule owner(data, [](void * p) noexcept { delete static_cast<std::vector<T> *>(p); });
    if (rows == 0)
      return nb::ndarray<nb::numpy, T>(data->data(), {data->size()}, owner);
    return nb::ndarray<nb::numpy, T>(data->data(), {rows, cols}, owner);
  }
} // namespace

void bindRunStatistics(nb::module_ & m)
{
  nb::class_<Stats>(m, "RunStatistics")
    .def(
      "__init__",
      [](Stats * self, int n, double bin_width, int bins, int modes) {
        new (self) Stats();
        self->configure(n, bin_width, bins, modes);
      },
      "n"_a, "bin_width"_a, "bins"_a, "modes"_a,
      "Statistics of n joints, a |residual| histogram of `bins` columns of `bin_width` [Nm] (the last: overflow), "
      "ticks per mode code in [0, modes).")
    .def(
      "add_rows",
      [](Stats & s, long rows, const In<double> & t, const In<double> & residual, const In<double> & tau,
         const In<std::uint8_t> & collision, const In<std::uint8_t> & collided, const In<std::int32_t> & mode,
         const In<std::int32_t> & fault_code) {
        if (rows < 0)
          throw reflexarm::ConfigError("RunStatistics.add_rows: rows must be >= 0; got " + std::to_string(rows));
        s.addRows(rows, rowsAtLeast(t, rows, 0, "t"), rowsAtLeast(residual, rows, s.n, "residual"),
                  rowsAtLeast(tau, rows, s.n, "tau"), rowsAtLeast(collision, rows, 0, "collision"),
                  rowsAtLeast(collided, rows, s.n, "collided"), rowsAtLeast(mode, rows, 0, "mode"),
                  rowsAtLeast(fault_code, rows, 0, "fault_code"));
      },
      "rows"_a, "t"_a, "residual"_a, "tau"_a, "collision"_a, "collided"_a, "mode"_a, "fault_code"_a,
      "Fold the first `rows` rows of the recorded block (in time order, after the rows folded before).")
    .def_ro("n", &Stats::n)
    .def_ro("bins", &Stats::bins)
    .def_ro("bin_width", &Stats::bin_width)
    .def_ro("ticks", &Stats::ticks)
    .def_ro("t_first", &Stats::t_first)
    .def_ro("t_last", &Stats::t_last)
    .def_ro("collision_ticks", &Stats::collision_ticks)
    .def_ro("collision_events", &Stats::collision_events)
    .def_ro("first_collision_t", &Stats::first_collision_t)
    .def_ro("last_collision", &Stats::last_collision)
    .def_ro("fault_ticks", &Stats::fault_ticks)
    .def_prop_ro("max_abs_residual", [](const Stats & s) { return copyOf(s.max_abs_residual); }, nb::rv_policy::move)
    .def_prop_ro("t_max_abs_residual", [](const Stats & s) { return copyOf(s.t_max_abs_residual); }, nb::rv_policy::move)
    .def_prop_ro("max_abs_tau", [](const Stats & s) { return copyOf(s.max_abs_tau); }, nb::rv_policy::move)
    .def_prop_ro("collided_ticks", [](const Stats & s) { return copyOf(s.collided_ticks); }, nb::rv_policy::move)
    .def_prop_ro("mode_ticks", [](const Stats & s) { return copyOf(s.mode_ticks); }, nb::rv_policy::move)
    .def_prop_ro(
      "counts",
      [](const Stats & s) { return copyOf(s.counts, static_cast<size_t>(s.n), static_cast<size_t>(s.bins)); },
      nb::rv_policy::move, "(n, bins) ticks per |residual| bin per joint.");
}
