// How many CPUs the process may use, and work shared among threads: one policy for every fork-join in the project.
#pragma once

#include <cstdint>
#include <functional>

namespace voxfmt {

/// The CPUs this process may run on: its affinity mask, which Slurm (--cpus-per-task), taskset, cgroup cpusets
/// and containers narrow, unlike std::thread::hardware_concurrency(), which counts the whole machine. At least 1.
unsigned usable_cores();

/// Runs work(0), ..., work(workers - 1) side by side, on workers - 1 new threads and the calling one, and returns
/// when all have (workers 0 counts as 1). A thread that cannot be started (a process at its thread limit) is not an
/// error: the caller runs that share after its own, so the work is done either way, only slower. `work` must not throw;
/// catch inside and report through the shared state.
void run_workers(unsigned workers, const std::function<void(unsigned worker)>& work);

/// This machine's physical memory in bytes (8 GiB where it cannot be read): what a long job checks its estimate
/// against before it starts, so that it is refused with figures instead of killed halfway.
uint64_t physical_memory_bytes();

/// The bytes a job may plan to use when its user names no limit: 3/4 of physical memory, leaving the rest to the
/// system and the caller's own process. The one default for the bake's --max-memory and the batch outputs' guard.
uint64_t default_memory_limit_bytes();

}  // namespace voxfmt
