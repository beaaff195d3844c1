#include "batch_progress.h"

#include "commands.h"

#include <sys/ioctl.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <iomanip>
#include <iostream>
#include <sstream>

namespace voxfmt::cli {

void EtaModel::add(double bytes, double seconds) {
  n_ += 1;
  sx_ += bytes;
  sy_ += seconds;
  sxx_ += bytes * bytes;
  sxy_ += bytes * seconds;
}

double EtaModel::predict(double bytes) const {
  const double mx = sx_ / n_, my = sy_ / n_, var = sxx_ / n_ - mx * mx;
  double b = var > 1e-9 * (mx * mx + 1) ? (sxy_ / n_ - mx * my) / var : 0;
  if (b < 0) b = 0;
  return std::max(0.0, my + b * (bytes - mx));
}

std::string clock_text(double seconds) {
  const long s = long(std::lround(std::max(0.0, seconds)));
  char text[32];
  if (s >= 3600)
    std::snprintf(text, sizeof text, "%ld:%02ld:%02ld", s / 3600, s / 60 % 60, s % 60);
  else
    std::snprintf(text, sizeof text, "%ld:%02ld", s / 60, s % 60);
  return text;
}

void BatchProgress::draw(const Snapshot& now) const {
  if (!bar_) return;
  std::ostringstream eta;
  if (eta_.ready()) {
    // The work left, spread over the lanes, but never less than the longest bake still running.
    double work = 0, longest_running = 0;
    for (double bytes : now.queued_bytes) work += eta_.predict(bytes);
    for (const Running& r : now.running) {
      const double left = std::max(0.0, eta_.predict(r.input_bytes) - r.elapsed_s);
      work += left;
      longest_running = std::max(longest_running, left);
    }
    const size_t lanes = std::max<size_t>(1, std::min(now.lanes, now.total - now.finished));
    eta << "ETA " << clock_text(std::max(work / double(lanes), longest_running));
  } else {
    eta << "ETA --:--";
  }
  winsize ws{};
  const int columns = ::ioctl(STDERR_FILENO, TIOCGWINSZ, &ws) == 0 && ws.ws_col > 20 ? ws.ws_col : 80;
  constexpr int kBar = 24;
  const int filled = now.total ? int(double(kBar) * double(now.finished) / double(now.total)) : kBar;
  std::ostringstream line;
  line << "[" << std::string(size_t(filled), '#') << std::string(size_t(kBar - filled), '.') << "] " << now.finished
       << "/" << now.total << "  " << now.failed << " failed  " << clock_text(now.elapsed_s) << " elapsed  "
       << eta.str();
  for (const Running& r : now.running) line << "  " << terminal_safe(r.name);  // a mesh's name may hold escapes
  std::string text = line.str();
  // At most columns - 1 columns, cut before a character, never inside its UTF-8 bytes. A character of three or four
  // bytes is counted two columns wide (CJK, emoji), one of one or two bytes one: never more than the terminal holds.
  size_t used = 0, end = 0;
  for (; end < text.size(); ++end) {
    const uint8_t byte = uint8_t(text[end]);
    if ((byte & 0xC0) == 0x80) continue;  // inside a character
    const size_t width = byte >= 0xE0 ? 2 : 1;
    if (used + width > size_t(columns - 1)) break;
    used += width;
  }
  text.resize(end);
  std::cerr << "\r\033[K" << text << std::flush;
}

void BatchProgress::clear() const {
  if (bar_) std::cerr << "\r\033[K" << std::flush;
}

void BatchProgress::report(const nlohmann::json& record, size_t done, size_t total) const {
  const bool failed = record["status"] == "failed";
  if (quiet_) return;
  if (bar_) {
    if (!failed) return;  // the bar shows the rest
    std::cerr << "\r\033[K";
  }
  std::ostringstream line;
  line << "[" << done << "/" << total << "] ";
  if (failed)
    line << "FAILED " << record["error"]["code"].get<std::string>() << ": "
         << record["error"]["message"].get<std::string>();
  else
    line << "ok     " << record["input"].get<std::string>() << " (" << std::fixed << std::setprecision(2)
         << record.value("wall_s", 0.0) << " s)";
  std::cerr << terminal_safe(line.str()) << "\n";  // a mesh's name and a child's message are not ours to print raw
}

}  // namespace voxfmt::cli
