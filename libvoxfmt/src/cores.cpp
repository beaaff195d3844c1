#include "voxfmt/detail/cores.h"

#include <algorithm>
#include <thread>
#include <vector>

#if defined(__linux__)
#include <sched.h>
#endif

namespace voxfmt {

unsigned usable_cores() {
#if defined(__linux__)
  cpu_set_t mask;
  CPU_ZERO(&mask);
  if (sched_getaffinity(0, sizeof mask, &mask) == 0) return std::max(1, CPU_COUNT(&mask));
#endif
  return std::max(1u, std::thread::hardware_concurrency());
}

void run_workers(unsigned workers, const std::function<void(unsigned worker)>& work) {
  workers = std::max(workers, 1u);
  std::vector<std::thread> threads;
  unsigned started = 1;
  try {
    threads.reserve(workers - 1);
    for (; started < workers; ++started) threads.emplace_back(work, started);
  } catch (...) {  // std::system_error (no thread to be had) or bad_alloc: the caller takes over the rest
  }
  work(0);
  for (unsigned w = started; w < workers; ++w) work(w);
  for (std::thread& t : threads) t.join();
}

}  // namespace voxfmt
