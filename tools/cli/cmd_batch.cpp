// `voxfmt batch INPUT... -o OUTDIR`: bake a library of meshes, in parallel, resumable, shardable.
//
// Each mesh is baked by a child process, `voxfmt build MESH -o OUT --json` of this very executable, rather
// than by a task in this process:
//  - a broken mesh can crash (CGAL assertions, stack overflow), exhaust memory or hang; in a child that
//    costs one recorded failure (CRASHED, OUT_OF_MEMORY, TIMEOUT) instead of the whole batch, and a timeout is
//    a plain SIGKILL;
//  - libvoxfmt's HDF5 calls are not thread-safe and TBB's thread limit is process-wide, so in-process meshes
//    would have to serialise their writes and share one --threads setting;
//  - SIGKILL semantics stay simple: children die with the parent (PR_SET_PDEATHSIG), every asset appears by an
//    atomic rename, and the manifest is appended and fsynced line by line, so a rerun sees finished assets as
//    up to date and cleans the `*.partial-*` files of killed bakes.
// The cost, one process start per mesh (~30 ms), is small beside a bake. `build` and `batch` share the option
// registration (bake_options.h), and a child gets the same settings spelled out in full.
//
// This file schedules the children and keeps the counts; batch_inputs finds the meshes and names the assets,
// batch_manifest keeps the records (and decides nothing), batch_progress draws.
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <iterator>
#include <set>
#include <sstream>
#include <thread>

#include "bake_options.h"
#include "batch_inputs.h"
#include "batch_manifest.h"
#include "batch_progress.h"
#include "child_process.h"
#include "commands.h"
#include "json_report.h"
#include "report.h"
#include "voxfmt/bake/bake.h"
#include "voxfmt/detail/atomic_file.h"
#include "voxfmt/detail/cores.h"
#include "voxfmt/detail/json_path.h"
#include "voxfmt/io.h"
#include "voxfmt/version.h"

namespace voxfmt::cli {

namespace fs = std::filesystem;

namespace {

struct Options {
  std::vector<std::string> inputs;
  std::string output_dir;
  unsigned jobs = 0;
  std::string shard = "0/1";
  bool force = false;
  bool retry_failed = false;
  double timeout = 0;
  size_t max_memory_mib = 0;
  std::string manifest;
  bool json = false;
  bool quiet = false;
  bool report = false;
  bool prune = false;      ///< remove the assets of recorded meshes no longer among the inputs
  std::string report_dir;  ///< empty: OUTDIR/report
  bake::Settings bake;

  fs::path report_folder() const { return report_dir.empty() ? fs::path(output_dir) / "report" : fs::path(report_dir); }
};

volatile std::sig_atomic_t g_interrupted = 0;
void on_signal(int signal_number) { g_interrupted = signal_number; }
volatile std::sig_atomic_t g_suspend = 0;  // Ctrl-Z (SIGTSTP): the batch stops its bakes, then itself
void on_suspend(int) { g_suspend = 1; }

std::string signal_name(int signal_number) {
  const char* name = ::strsignal(signal_number);
  return name ? name : "unknown signal";
}

struct Counts {
  size_t built = 0, up_to_date = 0, failed = 0;
  size_t failed_before = 0;  ///< of `failed`: unchanged since a run that failed deterministically, not retried
};

class Runner {
 public:
  explicit Runner(const Options& o) : o_(o) {}
  int run();
  /// With --json, the batch's summary (printed by the caller, once the report has been added to it).
  nlohmann::json& summary() { return summary_; }

 private:
  nlohmann::json base_record(const BatchItem& item) const;
  bool up_to_date(const BatchItem& item, const std::string& sha, nlohmann::json& record) const;
  const nlohmann::json* failed_before(const BatchItem& item, const std::string& sha) const;
  nlohmann::json finish_record(const BatchItem& item, const ChildResult& child,
                               const std::vector<std::string>& command);
  BatchProgress::Snapshot snapshot() const;
  // The stages of run(), in order.
  void select_inputs();
  void open_manifest();
  bool created_output_dir_ = false;  ///< select_inputs made OUTDIR (removed again if the manifest is refused)
  void plan();
  void find_removed();
  bake::Settings bake_settings();
  void announce(size_t stale_removed) const;
  bool bake_all(const bake::Settings& settings);
  void record_finished(const std::vector<ChildResult>& finished);
  void record_bake(const ChildResult& child);
  void append(const nlohmann::json& record);
  void report(bool interrupted);

  const Options& o_;
  nlohmann::json summary_;
  Shard shard_;
  std::vector<BatchItem> mine_;       ///< this shard's meshes
  size_t all_count_ = 0;              ///< every shard's
  std::vector<std::string> skipped_;  ///< what the folder scans left out ("PATH: why"), said as warnings
  std::string manifest_path_;
  std::unique_ptr<Manifest> manifest_;
  nlohmann::json parameters_;
  std::unique_ptr<BatchProgress> progress_;
  unsigned jobs_ = 1, threads_ = 1;
  std::chrono::steady_clock::time_point start_;
  // Work of this run.
  struct Job {
    BatchItem item;
    std::string sha;  ///< of the source when planned; empty if unreadable
  };
  std::vector<Job> todo_;
  size_t not_in_inputs_ = 0;           ///< outputs recorded in the manifest whose mesh is not among the inputs
  std::vector<std::string> prunable_;  ///< of those, the assets --prune may remove (inside OUTDIR, .vox.h5)
  size_t next_ = 0;
  struct Running {
    size_t index;
    std::chrono::steady_clock::time_point start;
    std::vector<std::string> command;
  };
  std::map<size_t, Running> running_;
  struct Stopped {
    ChildResult child;
    std::chrono::steady_clock::time_point until;  ///< recorded from then on, unless the batch is stopped
  };
  std::vector<Stopped> stopped_;  ///< bakes ended by a stop signal, held back (record_finished)
  size_t finished_ = 0;
  Counts counts_;
  std::vector<nlohmann::json> failures_;
};

// A failed mesh in the summary's "failures": its paths as the manifest stores them (escaped text, and the exact
// bytes in hex where they are not UTF-8), so a program finds the very file.
nlohmann::json failure_entry(const BatchItem& item, const nlohmann::json& error, bool retried) {
  nlohmann::json entry = {{"code", error["code"]}, {"message", error["message"]}, {"retried", retried}};
  set_path(entry, "input", item.input);
  set_path(entry, "output", item.output);
  return entry;
}

nlohmann::json Runner::base_record(const BatchItem& item) const {
  nlohmann::json record = {{"status", "ok"},
                           {"error", nullptr},
                           {"input_bytes", item.input_bytes},
                           {"build_parameters", parameters_},
                           {"tool_version", VOXFMT_VERSION_STRING}};
  set_path(record, "input", item.input);
  set_path(record, "output", item.output);
  return record;
}

// Whether an asset whose manifest record no longer matches it (touched, copied, its manifest lost) still reads: its
// provenance alone does not say (a file damaged past its provenance group read as up to date). A file too large for
// the read budget (the bakes' --max-memory where given) cannot be judged here and is taken by its provenance.
bool still_reads(const std::string& output, uint64_t max_memory_mib) {
  ReadOptions read;
  read.level = ValidationLevel::Quick;
  if (max_memory_mib > 0) read.max_memory_bytes = max_memory_mib << 20;
  for (const Issue& issue : validate_file(output, read))
    if (issue.severity == Severity::Error && issue.code != IssueCode::OutOfMemory) return false;
  return true;
}

// Same source bytes, build parameters and tool version: by the manifest (its record for this output, and the
// file still has the size and mtime recorded there), else by the asset's own provenance and a read of the file.
bool Runner::up_to_date(const BatchItem& item, const std::string& sha, nlohmann::json& record) const {
  if (o_.force || sha.empty()) return false;
  const FileStamp file = stamp(item.output);
  if (!file.exists) return false;
  const nlohmann::json* last = manifest_->last(item.output);
  const std::string last_status = last ? text_field(*last, "status") : "";
  // The manifest's record is of this bake (its figures still hold) ...
  const bool same_bake =
      (last_status == "ok" || last_status == "up_to_date") && text_field(*last, "source_sha256") == sha &&
      text_field(*last, "tool_version") == VOXFMT_VERSION_STRING && last->contains("build_parameters") &&
      same_parameters((*last)["build_parameters"], parameters_);
  // ... and of this very file.
  if (same_bake && integer_field(*last, "file_size_bytes") == int64_t(file.size) &&
      integer_field(*last, "output_mtime_ns") == file.mtime_ns) {
    record = nullptr;  // the manifest already says so
    return true;
  }
  Result<Provenance> provenance = read_provenance(item.output);
  if (!provenance) return false;  // unreadable, foreign or damaged: rebuild
  const Provenance& p = provenance.value();
  if (p.source_sha256 != sha || p.generator_version != VOXFMT_VERSION_STRING ||
      !same_parameters(p.build_parameters_json, parameters_) || !still_reads(item.output, o_.max_memory_mib))
    return false;
  // A touched or copied asset keeps its bake's figures (time, triangles, memory), which the report shows.
  record = same_bake ? *last : nlohmann::json::object();
  record.update(base_record(item));
  record["status"] = "up_to_date";
  record["source_sha256"] = sha;
  record["file_size_bytes"] = file.size;
  record["output_mtime_ns"] = file.mtime_ns;
  nlohmann::json warnings = nlohmann::json::array();
  for (const BuildWarning& w : p.build_warnings) warnings.push_back({{"code", w.code}, {"message", w.message}});
  record["warnings"] = warnings;
  record["created_utc"] = p.created_utc;
  record["finished_utc"] = bake::utc_now();
  return true;
}

// The manifest's last record for this output is a failure that would happen again: same source, parameters and
// tool version, and a code that depends only on the mesh.
const nlohmann::json* Runner::failed_before(const BatchItem& item, const std::string& sha) const {
  if (o_.force || o_.retry_failed || sha.empty()) return nullptr;
  const nlohmann::json* last = manifest_->last(item.output);
  if (!last || text_field(*last, "status") != "failed" || !last->contains("error") || !(*last)["error"].is_object() ||
      text_field((*last)["error"], "message").empty())
    return nullptr;
  const std::string code = text_field((*last)["error"], "code");
  if (code.empty() || transient_failure(code) || text_field(*last, "source_sha256") != sha ||
      text_field(*last, "tool_version") != VOXFMT_VERSION_STRING || !last->contains("build_parameters") ||
      !same_parameters((*last)["build_parameters"], parameters_))
    return nullptr;
  return last;
}

nlohmann::json Runner::finish_record(const BatchItem& item, const ChildResult& child,
                                     const std::vector<std::string>& command) {
  nlohmann::json record = base_record(item);
  record["wall_s"] = child.seconds;
  record["finished_utc"] = bake::utc_now();
  const nlohmann::json summary = nlohmann::json::parse(child.out, nullptr, false);
  const bool has_summary = summary.is_object() && summary.contains("status");
  if (child.exit_code == 0 && has_summary && summary["status"] == "ok") {
    for (const char* key :
         {"source_sha256", "timings_s", "total_s", "peak_memory_bytes", "file_size_bytes", "input_vertices",
          "input_triangles", "closed", "voxelmap", "pointshell", "volume", "warnings"})
      if (summary.contains(key)) record[key] = summary[key];
    record["output_mtime_ns"] = stamp(item.output).mtime_ns;
    return record;
  }
  // Failed: one code and one message, whatever the way the child ended.
  std::string code, message;
  std::string last_error_line;  // the child's own last words, for crashes
  {
    std::istringstream lines(child.err);
    for (std::string line; std::getline(lines, line);)
      if (!line.empty()) last_error_line = line;
  }
  if (child.timed_out) {
    code = code_name(IssueCode::Timeout);
    std::ostringstream text;
    text << item.input << ": not finished after " << o_.timeout << " s (--timeout); the bake was killed";
    message = text.str();
  } else if (child.signal) {
    code = code_name(IssueCode::Crashed);
    message = item.input + ": voxfmt build was killed by signal " + std::to_string(child.signal) + " (" +
              signal_name(child.signal) + ")" +
              (child.signal == SIGKILL ? " — by the kernel's out-of-memory killer or by another process" : "") +
              (last_error_line.empty() ? "" : "; its last message: " + last_error_line);
  } else if (has_summary && summary["status"] == "error" && !text_field(summary, "code").empty()) {
    code = text_field(summary, "code");
    message = text_field(summary, "message");
  } else {
    code = code_name(IssueCode::Internal);
    message = item.input + ": voxfmt build exited with code " + std::to_string(child.exit_code) + " without a summary" +
              (last_error_line.empty() ? "" : ": " + last_error_line);
  }
  if (has_summary && summary.contains("source_sha256")) record["source_sha256"] = summary["source_sha256"];
  record["status"] = "failed";
  record["error"] = {{"code", code}, {"message", message}};
  record["command"] = command;  // to reproduce it alone
  remove_stale_partials({item.output});
  return record;
}

BatchProgress::Snapshot Runner::snapshot() const {
  BatchProgress::Snapshot now;
  const auto clock = std::chrono::steady_clock::now();
  now.total = todo_.size();
  now.finished = finished_;
  now.failed = counts_.failed;
  now.lanes = jobs_;
  for (size_t i = next_; i < todo_.size(); ++i) now.queued_bytes.push_back(double(todo_[i].item.input_bytes));
  for (const auto& [id, r] : running_)
    now.running.push_back({fs::path(todo_[r.index].item.input).filename().string(),
                           double(todo_[r.index].item.input_bytes),
                           std::chrono::duration<double>(clock - r.start).count()});
  now.elapsed_s = std::chrono::duration<double>(clock - start_).count();
  return now;
}

int Runner::run() {
  start_ = std::chrono::steady_clock::now();
  progress_ = std::make_unique<BatchProgress>(::isatty(STDERR_FILENO) && !o_.json, o_.quiet || o_.json);
  shard_ = parse_shard(o_.shard);
  select_inputs();
  try {
    open_manifest();
  } catch (const UsageError&) {  // a refused manifest leaves no folder made for it
    std::error_code ec;
    if (created_output_dir_) fs::remove(o_.output_dir, ec);  // only if still empty
    throw;
  }
  std::vector<std::string> outputs;
  for (const BatchItem& item : mine_) outputs.push_back(item.output);
  outputs.push_back(manifest_path_);
  const size_t stale = remove_stale_partials(outputs);
  parameters_ = build_parameters(o_.bake);
  plan();
  find_removed();
  const bake::Settings settings = bake_settings();
  announce(stale);
  const bool interrupted = bake_all(settings);
  report(interrupted);
  if (interrupted) return 128 + int(g_interrupted);
  return counts_.failed ? kExitInvalid : kExitOk;
}

// This shard's meshes (mine_) among every input's (all_count_).
void Runner::select_inputs() {
  std::vector<BatchItem> all = collect_inputs(o_.inputs, o_.output_dir, &skipped_);
  if (!o_.quiet && !o_.json)
    for (const std::string& line : skipped_) std::cerr << "voxfmt batch: warning: " << terminal_safe(line) << "\n";
  if (all.empty())
    throw UsageError("no meshes found in the inputs (directories are scanned for extensions assimp reads)");
  all_count_ = all.size();
  if (o_.report && shard_.count == 1) {  // refused now, not after the bakes (a shard's batch writes no report)
    if (const Status usable = report::check_report_folder(o_.report_folder().string()); !usable)
      throw UsageError(usable.error().message + " (--report-dir)");
    const fs::path folder = fs::absolute(o_.report_folder()).lexically_normal();
    for (const BatchItem& item : all) {
      const fs::path inside = fs::absolute(item.output).lexically_normal().lexically_relative(folder);
      if (!inside.empty() && *inside.begin() != "..")
        throw UsageError(item.key + " would be baked into " + folder.string() +
                         ", the report's folder: choose another with --report-dir");
    }
  }
  // --manifest naming one of the assets (any shard's): the asset's rename would replace the manifest. Compared where
  // the writes land: through links (a link's target need not exist yet), then folders resolved.
  if (!o_.manifest.empty()) {
    const auto landing = [](const std::string& path) {
      const Result<std::string> target = output_target(path);
      std::error_code ec;
      return fs::weakly_canonical(target ? target.value() : path, ec);
    };
    const fs::path manifest = landing(o_.manifest);
    for (const BatchItem& item : all)
      if (!manifest.empty() && landing(item.output) == manifest)
        throw UsageError("--manifest " + o_.manifest + " is the asset of " + item.input +
                         ": the bake would replace the manifest (choose another file)");
  }
  // Made only once the inputs are known good: a refused batch leaves no empty folder behind.
  std::error_code ec;
  created_output_dir_ = !fs::exists(o_.output_dir, ec);
  fs::create_directories(o_.output_dir, ec);
  if (ec || !fs::is_directory(o_.output_dir))
    throw UsageError(o_.output_dir + ": cannot create output directory" + (ec ? ": " + ec.message() : ""),
                     IssueCode::WriteFailed);
  for (BatchItem& item : all)
    if (shard_.contains(item.key)) mine_.push_back(std::move(item));
}

// One manifest per shard, so shards running at once never write the same file.
void Runner::open_manifest() {
  manifest_path_ = !o_.manifest.empty() ? o_.manifest
                   : shard_.count == 1  ? (fs::path(o_.output_dir) / "manifest.jsonl").string()
                                        : (fs::path(o_.output_dir) / ("manifest.shard-" + std::to_string(shard_.index) +
                                                                     "-of-" + std::to_string(shard_.count) + ".jsonl"))
                                             .string();
  try {
    manifest_ = std::make_unique<Manifest>(manifest_path_);
  } catch (const std::runtime_error& e) {
    throw UsageError(e.what(), IssueCode::WriteFailed);
  }
}

// What is up to date is recorded (if the manifest does not say so already) and skipped, as is what failed before
// and would fail again; the rest is todo_, largest first.
void Runner::plan() {
  for (const BatchItem& item : mine_) {
    const Result<std::string> hashed = bake::sha256_file(item.input);
    const std::string sha = hashed ? hashed.value() : std::string();  // unreadable: the bake reports it properly
    nlohmann::json record;
    if (up_to_date(item, sha, record)) {
      ++counts_.up_to_date;
      if (!record.is_null()) append(record);
      continue;
    }
    if (const nlohmann::json* failure = failed_before(item, sha)) {
      ++counts_.failed;
      ++counts_.failed_before;
      failures_.push_back(failure_entry(item, (*failure)["error"], false));
      continue;
    }
    todo_.push_back({item, sha});
  }
  // Largest first: the long bakes start early and the small ones fill the gaps (shorter makespan).
  std::stable_sort(todo_.begin(), todo_.end(),
                   [](const Job& a, const Job& b) { return a.item.input_bytes > b.item.input_bytes; });
}

// The outputs the manifest records whose mesh is no longer among this run's inputs (this shard's): a mesh deleted
// or renamed. Said; with --prune its asset is removed and a "removed" record appended, which the next compaction
// drops. Only an asset a batch could have written: a `.vox.h5` file or link (never a folder) inside OUTDIR — a
// record is text anyone may have edited, and must not name a file elsewhere for deletion.
void Runner::find_removed() {
  std::set<std::string> current;
  for (const BatchItem& item : mine_) current.insert(manifest_->key_of(item.output));
  const std::string inside = report::resolved_folder(o_.output_dir) + "/";
  const std::string suffix = ".vox.h5";
  for (const auto& [key, record] : manifest_->records()) {
    if (current.count(key)) continue;
    ++not_in_inputs_;
    const std::string output = path_of(record, "output");
    if (key.rfind(inside, 0) == 0 && output.size() > suffix.size() &&
        output.compare(output.size() - suffix.size(), suffix.size(), suffix) == 0)
      prunable_.push_back(output);
  }
  if (!o_.prune) return;
  for (const std::string& output : prunable_) {  // after the loop above: append() changes the records
    std::error_code ec;
    const fs::file_status status = fs::symlink_status(output, ec);
    ec.clear();
    if (fs::is_regular_file(status) || fs::is_symlink(status)) fs::remove(output, ec);
    if (ec)
      throw UsageError(output + ": cannot remove the asset of a mesh no longer among the inputs: " + ec.message(),
                       IssueCode::WriteFailed);
    nlohmann::json record = {
        {"status", "removed"}, {"finished_utc", bake::utc_now()}, {"tool_version", VOXFMT_VERSION_STRING}};
    set_path(record, "output", output);
    append(record);
  }
}

// Lanes (jobs_) and threads per bake (threads_) from the cores this task may use, and each bake's settings.
bake::Settings Runner::bake_settings() {
  const unsigned cores = usable_cores();  // what Slurm or taskset gives this task, not the whole node
  jobs_ = o_.jobs ? o_.jobs : cores;
  bake::Settings settings = o_.bake;
  if (settings.threads == 0)
    settings.threads = std::max(
        1u, cores / std::max<unsigned>(1, unsigned(std::min<size_t>(jobs_, std::max<size_t>(1, todo_.size())))));
  threads_ = settings.threads;
  // The same limit for the bake's up-front estimate: refused with the figures rather than killed halfway.
  if (o_.max_memory_mib > 0) settings.voxelmap.max_memory_bytes = uint64_t(o_.max_memory_mib) << 20;
  return settings;
}

void Runner::announce(size_t stale) const {
  if (o_.quiet || o_.json) return;
  std::cerr << "voxfmt batch: " << mine_.size() << " mesh(es)";
  if (shard_.count > 1)
    std::cerr << " in shard " << shard_.index << "/" << shard_.count << " (of " << all_count_ << ")";
  std::cerr << ": " << counts_.up_to_date << " up to date, ";
  if (counts_.failed_before) std::cerr << counts_.failed_before << " failed before (unchanged), ";
  std::cerr << todo_.size() << " to bake with -j " << jobs_ << " (" << threads_ << " thread(s) each)";
  if (stale) std::cerr << "; removed " << stale << " stale temporary file(s)";
  std::cerr << "\n";
  if (not_in_inputs_ > 0)
    std::cerr << "voxfmt batch: " << not_in_inputs_ << " recorded mesh(es) no longer among the inputs"
              << (o_.prune ? ": " + std::to_string(prunable_.size()) + " asset(s) in OUTDIR removed"
                           : std::string(" (--prune removes their assets)"))
              << "\n";
}

// The stop signals caught (g_interrupted) as long as it lives, unless the caller ignores them (nohup); restored
// after, so that a signal during --report does what it did before the batch.
class StopSignals {
 public:
  static constexpr int kSignals[] = {SIGINT, SIGTERM, SIGHUP};
  StopSignals() {
    struct sigaction action {};
    action.sa_handler = on_signal;
    sigemptyset(&action.sa_mask);
    for (size_t n = 0; n < std::size(kSignals); ++n) {
      sigaction(kSignals[n], nullptr, &before_[n]);
      if (before_[n].sa_handler != SIG_IGN) sigaction(kSignals[n], &action, nullptr);
    }
    action.sa_handler = on_suspend;
    sigaction(SIGTSTP, nullptr, &before_suspend_);
    if (before_suspend_.sa_handler != SIG_IGN) sigaction(SIGTSTP, &action, nullptr);
  }
  ~StopSignals() {
    for (size_t n = 0; n < std::size(kSignals); ++n) sigaction(kSignals[n], &before_[n], nullptr);
    sigaction(SIGTSTP, &before_suspend_, nullptr);
    // A Ctrl-Z caught after the last bake's check is not lost: the batch stops now, as it would have.
    if (g_suspend) {
      g_suspend = 0;
      std::raise(SIGTSTP);
    }
  }
  /// Ctrl-Z: the bakes, each in a process group of its own that the terminal does not reach, are stopped with the
  /// batch and continued with it; the time stopped counts toward no --timeout.
  /// Returns how long the batch was stopped.
  static std::chrono::steady_clock::duration suspend(ChildPool& pool) {
    g_suspend = 0;
    pool.signal_all(SIGSTOP);
    const auto stopped = std::chrono::steady_clock::now();
    struct sigaction stop {
    }, ours{};
    stop.sa_handler = SIG_DFL;
    sigemptyset(&stop.sa_mask);
    sigaction(SIGTSTP, &stop, &ours);
    std::raise(SIGTSTP);  // stops here until SIGCONT (an orphaned process group is not stopped: it goes on)
    sigaction(SIGTSTP, &ours, nullptr);
    pool.signal_all(SIGCONT);
    const auto stopped_for = std::chrono::steady_clock::now() - stopped;
    pool.pause_clocks(stopped_for);
    return stopped_for;
  }
  StopSignals(const StopSignals&) = delete;
  StopSignals& operator=(const StopSignals&) = delete;
  static bool is_one(int signal_number) {
    return std::find(std::begin(kSignals), std::end(kSignals), signal_number) != std::end(kSignals);
  }

 private:
  struct sigaction before_[std::size(kSignals)]{};
  struct sigaction before_suspend_ {};
};

// Runs todo_ in jobs_ child processes, recording each as it ends. Returns whether a signal stopped the batch.
bool Runner::bake_all(const bake::Settings& settings) {
  const std::vector<std::string> option_args = bake_option_args(settings);
  const std::string exe = self_executable();
  ChildLimits limits;
  limits.timeout_seconds = o_.timeout;
  limits.max_memory_bytes = o_.max_memory_mib * 1024 * 1024;
  const StopSignals catching;
  ChildPool pool;
  std::error_code ec;
  // Bakes still running when the batch stops (a signal, a record that cannot be written) are killed, and their
  // temporaries removed.
  const auto stop_running = [&] {
    pool.kill_all();
    std::vector<std::string> unfinished;  // those stopped_ holds back included
    for (const auto& [id, r] : running_) unfinished.push_back(todo_[r.index].item.output);
    remove_stale_partials(unfinished);
  };
  try {
    while ((next_ < todo_.size() || pool.running() > 0 || !stopped_.empty()) && !g_interrupted) {
      while (next_ < todo_.size() && pool.running() < jobs_ && !g_interrupted) {
        const BatchItem& item = todo_[next_].item;
        fs::create_directories(fs::path(item.output).parent_path(), ec);
        std::vector<std::string> command = {exe, "build", "-o", item.output, "--json"};
        command.insert(command.end(), option_args.begin(), option_args.end());
        command.insert(command.end(), {"--", item.input});  // a mesh named "-x.off" is a mesh, not an option
        pool.start(next_, command, limits);
        running_[next_] = {next_, std::chrono::steady_clock::now(), command};
        ++next_;
      }
      progress_->draw(snapshot());
      record_finished(pool.poll(250));
      if (g_suspend && !g_interrupted) {
        progress_->clear();  // the shell's prompt takes the line
        const auto stopped_for = StopSignals::suspend(pool);
        for (auto& [id, r] : running_) r.start += stopped_for;  // the bar's per-bake times and ETA leave it out
      }
    }
  } catch (...) {
    stop_running();
    progress_->clear();
    throw;
  }
  const bool interrupted = g_interrupted != 0;
  if (interrupted) stop_running();
  progress_->clear();
  return interrupted;
}

// A bake ended by a stop signal is held back a moment before it is recorded: the signal that stops the batch may
// reach the bake first where it is sent to every process (Slurm's scancel to the step's, systemd to the unit's;
// Ctrl-C does not reach the bakes, which run in process groups of their own), and such a bake is not the mesh's
// failure. Signalled alone, it is recorded (CRASHED) once the moment has passed.
void Runner::record_finished(const std::vector<ChildResult>& finished) {
  constexpr auto kStopGrace = std::chrono::seconds(1);
  const auto now = std::chrono::steady_clock::now();
  for (const ChildResult& child : finished) {
    // Killed by the signal that stops the batch: not recorded, its temporary removed, baked again by the next run.
    if (g_interrupted && child.signal) continue;
    if (StopSignals::is_one(child.signal))
      stopped_.push_back({child, now + kStopGrace});
    else
      record_bake(child);
  }
  for (auto it = stopped_.begin(); it != stopped_.end() && !g_interrupted;) {
    if (it->until > now) {
      ++it;
      continue;
    }
    record_bake(it->child);
    it = stopped_.erase(it);
  }
}

// A finished bake's record in the manifest, its counts, failures and progress.
void Runner::record_bake(const ChildResult& child) {
  const Running r = running_[child.id];
  running_.erase(child.id);
  const BatchItem& item = todo_[r.index].item;
  nlohmann::json record = finish_record(item, child, r.command);
  if (!record.contains("source_sha256")) record["source_sha256"] = todo_[r.index].sha;
  append(record);
  ++finished_;
  progress_->finished(double(item.input_bytes), child.seconds);
  if (record["status"] == "failed") {
    ++counts_.failed;
    failures_.push_back(failure_entry(item, record["error"], true));
  } else {
    ++counts_.built;
  }
  progress_->report(record, finished_, todo_.size());
}

// A record that cannot be written (disk full, `ulimit -f`) stops the batch as an output that cannot be written:
// WRITE_FAILED with the manifest's path and the system's reason, not an unexpected error.
void Runner::append(const nlohmann::json& record) {
  try {
    manifest_->append(record);
  } catch (const std::runtime_error& e) {
    throw UsageError(e.what(), IssueCode::WriteFailed);
  }
}

void Runner::report(bool interrupted) {
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  if (o_.json) {
    summary_ = nlohmann::json{{"meshes", mine_.size()},
                              {"meshes_all_shards", all_count_},
                              {"shard", {shard_.index, shard_.count}},
                              {"built", counts_.built},
                              {"up_to_date", counts_.up_to_date},
                              {"failed", counts_.failed},
                              {"failed_not_retried", counts_.failed_before},
                              {"not_in_inputs", not_in_inputs_},
                              {"pruned", o_.prune ? prunable_.size() : 0},
                              {"not_started", todo_.size() - finished_},
                              {"interrupted", interrupted},
                              {"seconds", seconds},
                              {"jobs", jobs_},
                              {"threads_per_bake", threads_},
                              {"output_dir", o_.output_dir},
                              {"manifest", manifest_path_},
                              {"failures", failures_},
                              {"skipped_inputs", skipped_}};
  } else {
    std::cout << "voxfmt batch: " << mine_.size() << " mesh(es) in " << terminal_safe(o_.output_dir);
    if (shard_.count > 1) std::cout << " (shard " << shard_.index << "/" << shard_.count << ")";
    std::cout << ": " << counts_.built << " built, " << counts_.up_to_date << " up to date, " << counts_.failed
              << " failed";
    if (counts_.failed_before)
      std::cout << " (" << counts_.failed_before
                << " unchanged since they failed before: not retried; --retry-failed retries them)";
    if (interrupted) std::cout << ", " << todo_.size() - finished_ << " not finished (interrupted)";
    std::cout << " in " << std::fixed << std::setprecision(1) << seconds << " s\n";
    if (!failures_.empty()) {
      std::cout << "failed:\n";
      for (const nlohmann::json& f : failures_)
        std::cout << "  " << f["code"].get<std::string>() << ": " << terminal_safe(f["message"].get<std::string>())
                  << "\n";
    }
    std::cout << "manifest: " << terminal_safe(manifest_path_) << "\n";
  }
}

// `batch --report`: the library's report once the batch is done (a shard's batch says when to write it instead).
// With --json it goes into the batch's summary as "report" (null for a shard, {"status": "error", ...} when it
// failed). The report's exit code, 0 if written.
int report_after_batch(const Options& o, nlohmann::json& summary) {
  if (parse_shard(o.shard).count != 1) {  // as the batch read it ("0/01" is one shard)
    std::cerr << "voxfmt batch: --report with --shard: run `voxfmt report " << terminal_safe(o.output_dir)
              << "` once every shard is done (it reads every shard's manifest)\n";
    if (o.json) summary["report"] = nullptr;
    return 0;
  }
  report::LibraryReportOptions options;
  options.library = o.output_dir;
  options.out = o.report_dir;
  options.manifest = o.manifest;
  options.threads = int(o.jobs);
  if (!o.json && !o.quiet) options.progress = report_progress();
  const Result<report::ReportInfo> info = report::write_library_report(options);
  if (!info) {
    if (o.json)
      summary["report"] = {
          {"status", "error"}, {"code", code_name(info.error().code)}, {"message", info.error().message}};
    return report_error("batch", info.error());
  }
  if (o.json)
    summary["report"] = report_summary_json(info.value());
  else
    print_report_summary(info.value());
  return 0;
}

}  // namespace

// Below this much address space a child cannot load its libraries (one aborts in its initializer, before main):
// measured ~140 MiB for a 64^3 bunny; a limit that low is a typo, refused rather than recorded as CRASHED.
constexpr unsigned long long kLeastBakeAddressSpaceMib = 256;

// --max-memory (decimal digits, whole_number): 0, or a limit a bake can
// start under and that shifts into bytes without wrapping.
void check_max_memory(size_t mib) {
  constexpr size_t kMostMib = size_t(1) << 40;
  if (mib != 0 && (mib < kLeastBakeAddressSpaceMib || mib > kMostMib))
    throw UsageError("--max-memory " + std::to_string(mib) + ": a bake's address space below " +
                     std::to_string(kLeastBakeAddressSpaceMib) +
                     " MiB cannot even start voxfmt (its libraries' threads and stacks), and above 2^40 MiB is no "
                     "limit: 0 for none, else " +
                     std::to_string(kLeastBakeAddressSpaceMib) + "..2^40");
}

// The command: the batch, then its report; every failure a coded error line (or JSON) and an exit code.
int run_batch(const Options& o) {
  try {
    check_max_memory(o.max_memory_mib);
    Runner runner(o);
    int exit_code = runner.run();
    if (o.report && exit_code < 128)  // not once stopped
      exit_code = std::max(exit_code, report_after_batch(o, runner.summary()));
    if (o.json) std::cout << to_text(runner.summary()) << "\n";  // stdout holds one JSON document
    return exit_code;
  } catch (const UsageError& e) {
    return report_error("batch", {e.code, e.what()}, o.json,
                        o.inputs.size() == 1 ? o.inputs.front() : std::to_string(o.inputs.size()) + " inputs");
  } catch (const std::bad_alloc&) {
    return report_error("batch", {IssueCode::OutOfMemory, "out of memory"}, o.json, o.output_dir);
  } catch (const std::exception& e) {
    return report_error("batch", {IssueCode::Internal, std::string("unexpected error: ") + e.what()}, o.json,
                        o.output_dir);
  }
}

void add_batch_command(CLI::App& app, int& exit_code) {
  auto o = std::make_shared<Options>();
  CLI::App* cmd = app.add_subcommand(
      "batch", "Bake many meshes into OUTDIR: parallel, skips what is up to date, resumable after a kill, shardable");
  cmd->add_option("inputs", o->inputs,
                  "Mesh files, directories (scanned recursively for extensions assimp reads) and list files "
                  "(@FILE, or *.txt/*.lst/*.list: one path per line, relative to the list; from a pipe or "
                  "@/dev/stdin, to the working directory)")
      ->required();
  cmd->add_option("-o,--output", o->output_dir, "Output directory; OUTDIR/<path below the input root>.vox.h5 per mesh")
      ->check(output_path())
      ->required();
  cmd->add_option("-j,--jobs", o->jobs, "Meshes baked at once (0 = one per core)")
      ->capture_default_str()
      ->transform(whole_number())
      ->check(CLI::Range(0u, kMaxThreads));
  cmd->add_option("--shard", o->shard, "Bake only shard I of N (I/N, 0-based): mesh k belongs to hash(name) mod N")
      ->capture_default_str();
  cmd->add_flag("--force", o->force, "Rebuild assets that are up to date (and retry every failure)");
  cmd->add_flag("--retry-failed", o->retry_failed,
                "Retry meshes whose earlier failure would recur (same source, options and tool version); TIMEOUT, "
                "CRASHED, OUT_OF_MEMORY, INTERNAL and WRITE_FAILED are always retried");
  cmd->add_option("--timeout", o->timeout, "Seconds one mesh may take before it is killed (TIMEOUT); 0 = no limit")
      ->capture_default_str()
      ->check(finite_number(true))
      ->check(CLI::Range(0.0, 1e7));
  cmd->add_option("--max-memory", o->max_memory_mib,
                  "MiB one bake may use: its address space (OUT_OF_MEMORY beyond), and what its voxelmap may need "
                  "(refused up front beyond, with the estimate); 0 = no limit, else at least " +
                      std::to_string(kLeastBakeAddressSpaceMib))
      ->capture_default_str()
      ->transform(whole_number());
  cmd->add_option("--manifest", o->manifest,
                  "Manifest file (JSON Lines); default OUTDIR/manifest.jsonl, or OUTDIR/manifest.shard-I-of-N.jsonl "
                  "with --shard")
      ->check(output_path());  // '' would silently be the default
  add_bake_options(*cmd, o->bake);
  cmd->add_flag("--prune", o->prune,
                "Remove the assets (and records) of meshes the manifest holds that are not among these inputs: "
                "deleted or renamed meshes");
  cmd->add_flag("--json", o->json, "Print the summary as JSON on stdout (no progress)");
  cmd->add_flag("-q,--quiet", o->quiet, "No progress or per-mesh lines; only the summary");
  cmd->add_flag("--report", o->report, "Then write the library's HTML report into OUTDIR/report (`voxfmt report`)");
  cmd->add_option("--report-dir", o->report_dir, "The report's folder instead of OUTDIR/report (implies --report)")
      ->check(output_path())
      ->each([o](const std::string&) { o->report = true; });
  cmd->footer(
      "\nExamples:\n"
      "  voxfmt batch meshes/ -o assets/                       # every mesh below meshes/, on every core\n"
      "  voxfmt batch meshes/ -o assets/ --retry-failed -j 2   # again: only what failed or changed\n"
      "  voxfmt batch /shared/meshes -o /shared/assets --shard 3/16 --timeout 3600   # one Slurm array task\n");
  cmd->callback([o, &exit_code] { exit_code = run_batch(*o); });
}

}  // namespace voxfmt::cli
