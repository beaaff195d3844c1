// How many CPUs the process may use, for sizing worker pools.
#pragma once

namespace voxfmt {

/// The CPUs this process may run on: its affinity mask, which Slurm (--cpus-per-task), taskset, cgroup cpusets
/// and containers narrow, unlike std::thread::hardware_concurrency(), which counts the whole machine. At least 1.
unsigned usable_cores();

}  // namespace voxfmt
