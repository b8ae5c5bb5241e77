// reflexarm::RunStatistics: running statistics of a closed-loop run, folded from its recorded rows block by
// block in C++ (reflexarm.sim.recording.RunStatistics computes the same numbers from a Trace in numpy).
//
// Per joint: the largest |residual| and the time of its first occurrence, the largest |command|, the ticks
// on which the joint crossed the threshold, and a histogram of |residual| (bins of `bin_width`, the last bin
// holding everything from (bins - 1) x bin_width up, NaN included); per run: the ticks with the collision
// flag, its rising edges (separate detections) and the first one's time, ticks per mode and ticks with a
// fault. Sized once by configure(); addRows() never allocates.
#pragma once

#include <cstdint>
#include <limits>
#include <vector>

namespace reflexarm
{

  struct RunStatistics
  {
    int n = 0;                ///< joints
    int bins = 0;             ///< histogram columns per joint (the last is the overflow bin)
    double bin_width = 0.1;   ///< [Nm]
    long ticks = 0;
    double t_first = std::numeric_limits<double>::quiet_NaN(), t_last = std::numeric_limits<double>::quiet_NaN();
    std::vector<double> max_abs_residual, t_max_abs_residual, max_abs_tau; ///< n each
    long collision_ticks = 0, collision_events = 0;
    double first_collision_t = std::numeric_limits<double>::quiet_NaN(); ///< NaN: none
    bool last_collision = false;
    std::vector<std::int64_t> collided_ticks; ///< n
    long fault_ticks = 0;
    std::vector<std::int64_t> mode_ticks;     ///< per mode code (modes)
    std::vector<std::int64_t> counts;         ///< n x bins, row-major

    /// Sizes and clears everything. Throws ConfigError for n < 1, bins < 2, a bin width <= 0 or modes < 1.
    void configure(int joints, double width, int columns, int modes);

    /// Folds `rows` recorded rows in time order (row-major: residual, tau and collided are rows x n). A mode
    /// code outside [0, modes) is counted in the last mode slot.
    void addRows(long rows, const double * t, const double * residual, const double * tau,
                 const std::uint8_t * collision, const std::uint8_t * collided, const std::int32_t * mode,
                 const std::int32_t * fault_code) noexcept;
  };

} // namespace reflexarm
