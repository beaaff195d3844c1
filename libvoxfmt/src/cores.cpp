#include "voxfmt/detail/cores.h"

#include <algorithm>
#include <thread>
#include <vector>

#if defined(__linux__)
#include <sched.h>
#endif
#include <unistd.h>

namespace voxfmt {

unsigned usable_cores() {
#if defined(__linux__)
  cpu_set_t mask;
  CPU_ZERO(&mask);
  if (sched_getaffinity(0, sizeof mask, &mask) == 0) return std::max(1, CPU_COUNT(&mask));
#endif
  return std::max(1u, std::thread::hardware_concurrency());
}

uint64_t physical_memory_bytes() {
  const long pages = ::sysconf(_SC_PHYS_PAGES), page = ::sysconf(_SC_PAGE_SIZE);
  return pages > 0 && page > 0 ? uint64_t(pages) * uint64_t(page) : uint64_t(8) << 30;
}

uint64_t default_memory_limit_bytes() { return physical_memory_bytes() / 4 * 3; }

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
