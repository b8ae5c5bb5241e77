// reflexarm::RunStatistics: see run_statistics.hpp. The numbers are those of
// reflexarm.sim.recording.RunStatistics.update on the same rows: a strictly larger |residual| moves the
// maximum (ties keep the earlier tick), the histogram index is trunc(clip(|r| / bin_width, 0, bins - 1)) with
// NaN in the overflow bin.
#include "reflexarm/run_statistics.hpp"

#include <cmath>
#include <string>

#include "reflexarm/params.hpp"

namespace reflexarm
{

  void RunStatistics::configure(int joints, double width, int columns, int modes)
  {
    if (joints < 1 || columns < 2 || !(width > 0.0) || modes < 1)
      throw ConfigError("RunStatistics: joints >= 1, bins >= 2, bin_width > 0 and modes >= 1 needed; got "
                        + std::to_string(joints) + ", " + std::to_string(columns) + ", " + std::to_string(width)
                        + ", " + std::to_string(modes));
    *this = RunStatistics{};
    n = joints;
    bins = columns;
    bin_width = width;
    max_abs_residual.assign(n, 0.0);
    t_max_abs_residual.assign(n, std::numeric_limits<double>::quiet_NaN());
    max_abs_tau.assign(n, 0.0);
    collided_ticks.assign(n, 0);
    mode_ticks.assign(modes, 0);
    counts.assign(static_cast<size_t>(n) * static_cast<size_t>(bins), 0);
  }

  void RunStatistics::addRows(long rows, const double * t, const double * residual, const double * tau,
                              const std::uint8_t * collision, const std::uint8_t * collided,
                              const std::int32_t * mode, const std::int32_t * fault_code) noexcept
  {
    if (rows <= 0)
      return;
    if (ticks == 0)
      t_first = t[0];
    t_last = t[rows - 1];
    ticks += rows;
    const double top = static_cast<double>(bins - 1);
    const int n_modes = static_cast<int>(mode_ticks.size());
    for (long k = 0; k < rows; ++k)
    {
      for (int j = 0; j < n; ++j)
      {
        const double r = std::fabs(residual[k * n + j]);
        if (r > max_abs_residual[j])
        {
          max_abs_residual[j] = r;
          t_max_abs_residual[j] = t[k];
        }
        const double a = std::fabs(tau[k * n + j]);
        if (a > max_abs_tau[j])
          max_abs_tau[j] = a;
        collided_ticks[j] += collided[k * n + j] != 0 ? 1 : 0;
        const double s = r / bin_width;
        const long idx = (std::isnan(s) || s >= top) ? bins - 1 : (s > 0.0 ? static_cast<long>(s) : 0);
        ++counts[static_cast<size_t>(j) * bins + idx];
      }
      const bool c = collision[k] != 0;
      if (c)
      {
        ++collision_ticks;
        if (!last_collision)
          ++collision_events;
        if (std::isnan(first_collision_t))
          first_collision_t = t[k];
      }
      last_collision = c;
      const int m = mode[k];
      ++mode_ticks[(m >= 0 && m < n_modes) ? m : n_modes - 1];
      if (fault_code[k] != 0)
        ++fault_ticks;
    }
  }

} // namespace reflexarm
