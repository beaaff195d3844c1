#include <gtest/gtest.h>

#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <new>
#include <stdexcept>
#include <thread>

#include "analytic_sphere.h"
#include "test_support.h"
#include "voxfmt/detail/atomic_file.h"
#include "voxfmt/detail/utf8.h"
#include "voxfmt/io.h"

namespace voxfmt {
namespace {

TEST(RoundTrip, EveryFieldSurvivesWriteAndRead) {
  const Asset a = test::make_full_asset();
  ASSERT_TRUE(validate_asset(a).empty());
  const std::string file = test::scratch_dir("roundtrip") + "/full.vox.h5";
  const Status written = write_asset(file, a, test::structural());
  ASSERT_TRUE(written) << written.error().message;

  std::vector<Issue> warnings;
  Result<Asset> read = read_asset(file, &warnings, test::structural_read());
  ASSERT_TRUE(read) << read.error().message;
  EXPECT_TRUE(warnings.empty());
  const Asset& b = read.value();

  EXPECT_EQ(b.version, kFormatVersion);
  EXPECT_EQ(b.up_axis, a.up_axis);
  EXPECT_EQ(b.bounds_min, a.bounds_min);
  EXPECT_EQ(b.bounds_max, a.bounds_max);

  EXPECT_EQ(b.voxelmap.origin, a.voxelmap.origin);
  EXPECT_EQ(b.voxelmap.voxel_size, a.voxelmap.voxel_size);
  EXPECT_EQ(b.voxelmap.dims, a.voxelmap.dims);
  EXPECT_EQ(b.voxelmap.distance_band, a.voxelmap.distance_band);
  EXPECT_EQ(b.voxelmap.margin, a.voxelmap.margin);
  EXPECT_EQ(b.voxelmap.distance_quantum, a.voxelmap.distance_quantum);
  EXPECT_EQ(b.voxelmap.estimate_quantum, a.voxelmap.estimate_quantum);
  EXPECT_EQ(b.voxelmap.lattice_error, a.voxelmap.lattice_error);
  EXPECT_EQ(b.voxelmap.bricks, a.voxelmap.bricks);
  EXPECT_EQ(b.voxelmap.brick_values, a.voxelmap.brick_values);
  EXPECT_EQ(b.voxelmap.lattice, a.voxelmap.lattice);

  EXPECT_EQ(b.point_shell.points, a.point_shell.points);
  EXPECT_EQ(b.point_shell.normals, a.point_shell.normals);
  EXPECT_EQ(b.point_shell.sphere_centers, a.point_shell.sphere_centers);
  EXPECT_EQ(b.point_shell.sphere_radii, a.point_shell.sphere_radii);
  EXPECT_EQ(b.point_shell.child_begin, a.point_shell.child_begin);
  EXPECT_EQ(b.point_shell.child_count, a.point_shell.child_count);
  EXPECT_EQ(b.point_shell.level_offsets, a.point_shell.level_offsets);
  EXPECT_EQ(b.point_shell.point_spacing, a.point_shell.point_spacing);
  EXPECT_EQ(b.point_shell.branching, a.point_shell.branching);

  EXPECT_EQ(b.mass.volume, a.mass.volume);
  EXPECT_EQ(b.mass.center_of_mass, a.mass.center_of_mass);
  EXPECT_EQ(b.mass.inertia, a.mass.inertia);

  EXPECT_EQ(b.provenance.generator, a.provenance.generator);
  EXPECT_EQ(b.provenance.generator_version, a.provenance.generator_version);
  EXPECT_EQ(b.provenance.source_file, a.provenance.source_file);
  EXPECT_EQ(b.provenance.source_sha256, a.provenance.source_sha256);
  EXPECT_EQ(b.provenance.build_parameters_json, a.provenance.build_parameters_json);
  EXPECT_EQ(b.provenance.dependency_versions, a.provenance.dependency_versions);
  EXPECT_EQ(b.provenance.build_warnings, a.provenance.build_warnings);
  EXPECT_EQ(b.provenance.created_utc, a.provenance.created_utc);
}

TEST(RoundTrip, OptionalFieldsMayBeAbsent) {
  Asset a = test::make_full_asset();
  a.voxelmap.margin.reset();
  a.point_shell.point_spacing.reset();
  a.point_shell.branching.reset();
  a.provenance.created_utc.clear();
  const std::string file = test::scratch_dir("optional") + "/minimal.vox.h5";
  ASSERT_TRUE(write_asset(file, a, test::structural()));
  Result<Asset> read = read_asset(file, nullptr, test::structural_read());
  ASSERT_TRUE(read) << read.error().message;
  EXPECT_FALSE(read.value().voxelmap.margin);
  EXPECT_FALSE(read.value().point_shell.point_spacing);
  EXPECT_FALSE(read.value().point_shell.branching);
  EXPECT_TRUE(read.value().provenance.created_utc.empty());
}

TEST(RoundTrip, WriteReplacesAnExistingFileAndLeavesNoTemporary) {
  const std::string dir = test::scratch_dir("replace");
  const std::string file = dir + "/a.vox.h5";
  Asset a = test::make_full_asset();
  ASSERT_TRUE(write_asset(file, a, test::structural()));
  a.mass.volume = 0.25;
  ASSERT_TRUE(write_asset(file, a, test::structural()));
  EXPECT_EQ(read_asset(file, nullptr, test::structural_read()).value().mass.volume, 0.25);
  size_t entries = 0;
  for (auto it = std::filesystem::directory_iterator(dir); it != std::filesystem::directory_iterator(); ++it) ++entries;
  EXPECT_EQ(entries, 1u);
}

TEST(RoundTrip, AReadBesideAWriteOnAnotherThreadWaitsForItInsteadOfStalling) {
  // An isolated read forks a child; forked while another thread was inside HDF5 (a bake writing its asset), the
  // child inherited HDF5's lock held and slept until the watchdog stopped it, 5 s, then once more: a Python
  // load() beside a bake() took 10 s, or failed. Writes and isolated reads now take turns.
  const Asset a = test::make_full_asset();
  const std::string dir = test::scratch_dir("read-beside-write");
  ASSERT_TRUE(write_asset(dir + "/read.vox.h5", a, test::structural()));
  std::atomic<bool> stop{false};
  std::thread writer([&] {
    while (!stop) ASSERT_TRUE(write_asset(dir + "/written.vox.h5", a, test::structural()));
  });
  double slowest = 0;
  for (int n = 0; n < 12; ++n) {
    const auto start = std::chrono::steady_clock::now();
    const Result<Asset> read = read_asset(dir + "/read.vox.h5", nullptr, test::structural_read());
    slowest = std::max(slowest, std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    EXPECT_TRUE(read) << read.error().message;
  }
  stop = true;
  writer.join();
  EXPECT_LT(slowest, 4.5);  // a stalled child sleeps 5 s; a read waiting its turn, far less (even under ASan)
}

TEST(ReadProvenance, ReadsOnlyTheProvenanceAndRefusesWhatReadAssetRefuses) {
  const std::string dir = test::scratch_dir("provenance");
  const Asset a = test::make_full_asset();
  ASSERT_TRUE(write_asset(dir + "/a.vox.h5", a, test::structural()));
  Result<Provenance> p = read_provenance(dir + "/a.vox.h5");
  ASSERT_TRUE(p) << p.error().message;
  EXPECT_EQ(p.value().generator, a.provenance.generator);
  EXPECT_EQ(p.value().source_sha256, a.provenance.source_sha256);
  EXPECT_EQ(p.value().build_parameters_json, a.provenance.build_parameters_json);
  EXPECT_EQ(p.value().build_warnings, a.provenance.build_warnings);

  Result<Provenance> missing = read_provenance(dir + "/none.vox.h5");
  ASSERT_FALSE(missing);
  EXPECT_EQ(missing.error().code, IssueCode::FileNotFound);
  { std::ofstream(dir + "/text.vox.h5") << "not hdf5"; }
  Result<Provenance> text = read_provenance(dir + "/text.vox.h5");
  ASSERT_FALSE(text);
  EXPECT_EQ(text.error().code, IssueCode::NotHdf5);
}

TEST(Write, RefusesAnInvalidAssetAndWritesNothing) {
  const std::string dir = test::scratch_dir("refuse");
  Asset a = test::make_full_asset();
  a.point_shell.child_begin[1] = 99;  // outside the tree
  const Status status = write_asset(dir + "/bad.vox.h5", a, test::structural());
  ASSERT_FALSE(status);
  EXPECT_EQ(status.error().code, IssueCode::InvalidAsset);
  EXPECT_EQ(status.error().object, "/pointshell/child_begin");
  EXPECT_NE(status.error().message.find("/pointshell/child_begin"), std::string::npos) << status.error().message;
  EXPECT_TRUE(std::filesystem::is_empty(dir));
}

TEST(Write, RefusesTextThatIsNotUtf8) {
  // Spec §1: every stored string is UTF-8; a reader refuses any other (STRING_NOT_UTF8), so no writer makes one.
  const std::string dir = test::scratch_dir("not-utf8");
  Asset a = test::make_full_asset();
  a.provenance.source_file = "b\xff.off";  // a file name from the file system may hold any bytes
  const Status status = write_asset(dir + "/bad.vox.h5", a, test::structural());
  ASSERT_FALSE(status);
  EXPECT_EQ(status.error().object, "/provenance/@source_file");
  EXPECT_NE(status.error().message.find("b\\xFF.off"), std::string::npos) << status.error().message;
  EXPECT_TRUE(std::filesystem::is_empty(dir));
}

TEST(Write, BeforeCommitCanAbortAndLeavesTheOldFile) {
  const std::string dir = test::scratch_dir("before-commit");
  const std::string path = dir + "/a.vox.h5";
  ASSERT_TRUE(write_asset(path, test::make_full_asset(), test::structural()));
  const auto old_size = std::filesystem::file_size(path);

  Asset changed = test::make_full_asset();
  changed.voxelmap.bricks.assign(changed.voxelmap.bricks.size(), Voxelmap::kCoarseOutside);
  changed.voxelmap.brick_values.clear();
  WriteOptions options;
  options.validation = ValidationLevel::Quick;  // an all-coarse map breaks no rule here; this is about the hook
  bool temporary_was_complete = false;
  options.before_commit = [&]() -> Status {
    // The temporary is flushed and closed by now: it reads back as a whole asset.
    for (const auto& entry : std::filesystem::directory_iterator(dir))
      if (entry.path().string().find(".partial-") != std::string::npos)
        temporary_was_complete = bool(read_asset(entry.path().string(), nullptr, test::structural_read()));
    return Error{IssueCode::WriteFailed, "checked and refused"};
  };
  const Status status = write_asset(path, changed, options);
  ASSERT_FALSE(status);
  EXPECT_EQ(status.error().message, "checked and refused");
  EXPECT_TRUE(temporary_was_complete);
  EXPECT_EQ(std::filesystem::file_size(path), old_size);
  EXPECT_EQ(std::distance(std::filesystem::directory_iterator(dir), std::filesystem::directory_iterator()), 1);

  options.before_commit = [] { return Status::success(); };
  ASSERT_TRUE(write_asset(path, changed, options));
  const Result<Asset> back = read_asset(path, nullptr, test::structural_read());
  ASSERT_TRUE(back);
  EXPECT_EQ(back.value().voxelmap.stored_count(), 0u);  // no value bricks: an empty dataset reads back empty
  EXPECT_EQ(back.value().voxelmap.value_brick_count(), 0u);
}

TEST(Write, FullRulesAreCheckedBeforeTheFileIsReplaced) {
  // Structurally fine, semantically wrong: a stored distance more than a voxel outside turned inside, among
  // neighbours outside. The default write checks every rule of `validate --level full` and keeps the earlier file.
  const std::string dir = test::scratch_dir("full-rules");
  const std::string path = dir + "/a.vox.h5";
  const Asset sphere = test::make_sphere_asset();  // exact: passes every rule
  ASSERT_TRUE(write_asset(path, sphere));
  const auto old_size = std::filesystem::file_size(path);
  Asset wrong = sphere;
  Voxelmap& vm = wrong.voxelmap;
  size_t stored = 0;
  while (
      !(Voxelmap::code_is_stored(vm.brick_values[stored]) && vm.decode(vm.brick_values[stored]) > 1.2 * vm.voxel_size))
    ++stored;
  vm.brick_values[stored] = vm.encode_stored(-vm.decode(vm.brick_values[stored]));
  ASSERT_FALSE(has_errors(validate_asset(wrong, ValidationLevel::Quick)));
  const Status status = write_asset(path, wrong);
  ASSERT_FALSE(status);
  EXPECT_EQ(status.error().code, IssueCode::InvalidAsset);
  EXPECT_TRUE(status.error().message.find("spec rule SIGN_MISMATCH") != std::string::npos ||
              status.error().message.find("spec rule DISTANCE_JUMP") != std::string::npos)
      << status.error().message;
  EXPECT_EQ(std::filesystem::file_size(path), old_size);
  EXPECT_EQ(std::distance(std::filesystem::directory_iterator(dir), std::filesystem::directory_iterator()), 1);

  WriteOptions quick;
  quick.validation = ValidationLevel::Quick;  // a caller may ask for the structural rules only
  EXPECT_TRUE(write_asset(path, wrong, quick));
}

TEST(Write, TellsItsProgressOnTheCallingThread) {
  test::SphereSpec fine;
  fine.voxel_size = 0.002;  // some 500 value bricks: several chunks to compress and bricks to check
  const Asset sphere = test::make_sphere_asset(fine);
  const std::string path = test::scratch_dir("write-progress") + "/a.vox.h5";
  std::vector<double> told;
  bool elsewhere = false;
  const std::thread::id caller = std::this_thread::get_id();
  WriteOptions options;
  options.progress_interval_s = 0;  // every piece of work
  options.progress = [&](double done) {
    told.push_back(done);
    elsewhere = elsewhere || std::this_thread::get_id() != caller;
  };
  ASSERT_TRUE(write_asset(path, sphere, options));
  EXPECT_FALSE(elsewhere);
  ASSERT_GE(told.size(), 5u);
  EXPECT_EQ(told.front(), 0.0);  // at once
  EXPECT_TRUE(std::is_sorted(told.begin(), told.end()));
  EXPECT_GT(told.back(), 0.9);
  EXPECT_LE(told.back(), 1.0);
}

TEST(Write, AProgressThatThrowsStopsTheWriteAndKeepsTheOldFile) {
  test::SphereSpec fine;
  fine.voxel_size = 0.002;
  const Asset sphere = test::make_sphere_asset(fine);
  const std::string dir = test::scratch_dir("write-progress-stop");
  const std::string path = dir + "/a.vox.h5";
  ASSERT_TRUE(write_asset(path, test::make_full_asset(), test::structural()));
  const auto old_size = std::filesystem::file_size(path);
  struct Cancelled {};  // not a std::exception: it must come through as it was thrown
  // Thrown at once, while chunks are compressed (on a worker that catches everything) and while the check ends.
  for (const int at : {0, 1, 3, 1000}) {
    for (const ValidationLevel level : {ValidationLevel::Quick, ValidationLevel::Full}) {
      int calls = 0;
      WriteOptions options;
      options.validation = level;
      options.progress_interval_s = 0;
      options.progress = [&](double) {
        if (calls++ == at) throw Cancelled{};
      };
      bool thrown = false;
      try {
        const Status status = write_asset(path, sphere, options);
        EXPECT_TRUE(status) << status.error().message;
      } catch (const Cancelled&) {
        thrown = true;
      }
      EXPECT_EQ(thrown, at != 1000) << "throw at call " << at;
      if (thrown) {
        EXPECT_EQ(std::filesystem::file_size(path), old_size) << at;
      } else {  // fewer reports than that: the sphere was written
        EXPECT_LT(calls, at);
        EXPECT_NE(std::filesystem::file_size(path), old_size);
        ASSERT_TRUE(write_asset(path, test::make_full_asset(), test::structural()));
      }
      EXPECT_EQ(std::distance(std::filesystem::directory_iterator(dir), std::filesystem::directory_iterator()), 1)
          << "a temporary left after a throw at call " << at;
    }
  }
}

TEST(Write, ReportsAnUnwritableDirectory) {
  const Status status = write_asset("/nonexistent-dir/x.vox.h5", test::make_full_asset(), test::structural());
  ASSERT_FALSE(status);
  EXPECT_EQ(status.error().code, IssueCode::WriteFailed);
  EXPECT_NE(status.error().message.find("/nonexistent-dir/x.vox.h5"), std::string::npos);
}

TEST(Errors, AnUncheckedFailedResultSaysWhatFailed) {
  // value() of a failed result threw std::bad_variant_access, which names nothing; now the error travels along.
  const Result<Asset> missing = read_asset("/nonexistent/voxfmt-test.vox.h5");
  ASSERT_FALSE(missing.ok());
  try {
    (void)missing.value();
    ADD_FAILURE() << "no throw";
  } catch (const BadResultAccess& e) {
    EXPECT_EQ(e.error().code, IssueCode::FileNotFound);
    EXPECT_NE(std::string(e.what()).find("FILE_NOT_FOUND"), std::string::npos) << e.what();
  }
  const Result<int> fine = 3;
  EXPECT_EQ(fine.value(), 3);
  EXPECT_THROW((void)fine.error(), std::logic_error);
  const Status succeeded = Status::success();  // a success has no error to hand out, as a Result has none
  EXPECT_THROW((void)succeeded.error(), BadResultAccess);
  const Status failed = Error(IssueCode::BadOption, "x");
  EXPECT_EQ(failed.error().code, IssueCode::BadOption);
}

TEST(Files, OnlyAnEndedProcessCountsAsGone) {
  // Whose temporaries may be swept (`export`, `report`): a process that has ended, never a live one or a name
  // that is not a process id.
  EXPECT_FALSE(process_is_gone(std::to_string(::getpid())));
  for (const char* not_a_pid : {"", "0", "-1", "12a", "1234567890", " 12"}) EXPECT_FALSE(process_is_gone(not_a_pid));
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) ::_exit(0);
  // Ended but not reaped, a zombie (as a bake killed with its batch stays where nothing reaps orphans): gone.
  siginfo_t info{};
  ASSERT_EQ(::waitid(P_PID, id_t(child), &info, WEXITED | WNOWAIT), 0);
  EXPECT_TRUE(process_is_gone(std::to_string(child)));
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  EXPECT_TRUE(process_is_gone(std::to_string(child)));  // reaped: the id names no process (until reused)
}

TEST(Files, ANameAsLongAsTheFileSystemAllowsIsWrittenAndItsDeadTemporariesFound) {
  // 255 bytes is a legal name; its temporary (the name and ".partial-PID-N") was not, so no write could succeed.
  const std::string dir = test::scratch_dir("long-name");
  const std::string name = std::string(248, 'n') + ".vox.h5", sibling = std::string(248, 'n') + ".vox.h6";
  ASSERT_EQ(name.size(), 255u);
  EXPECT_EQ(temporary_stem("short.vox.h5"), "short.vox.h5");
  const std::string stem = temporary_stem(name);
  EXPECT_LE(stem.size() + kPartialMarker.size() + 21, 255u);
  EXPECT_EQ(stem.compare(0, 100, name, 0, 100), 0);  // the name's start is kept, to be recognised
  EXPECT_NE(stem, temporary_stem(sibling));          // names that differ only at their end keep apart
  EXPECT_EQ(stem, temporary_stem(name));
  // A long name of two-byte characters is cut between characters, never inside one.
  std::string accented = "a";  // then "é"s: each starts at an odd byte
  while (accented.size() < 250) accented += "\xc3\xa9";
  EXPECT_EQ(temporary_stem(accented).find('~') % 2, 1u);

  ASSERT_TRUE(write_file_atomically(dir + "/" + name, std::string_view("bytes")));
  ASSERT_TRUE(write_file_atomically(dir + "/" + sibling, std::string_view("other")));
  std::ifstream written(dir + "/" + name);
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(written), {}), "bytes");

  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) ::_exit(0);
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  const std::string dead = dir + "/" + stem + std::string(kPartialMarker) + std::to_string(child) + "-0";
  const std::string alive = dir + "/" + stem + std::string(kPartialMarker) + std::to_string(::getpid()) + "-0";
  std::ofstream(dead) << "torn";
  std::ofstream(alive) << "being written";
  EXPECT_FALSE(dead_temporary_of(std::filesystem::directory_entry(dead), sibling));
  EXPECT_EQ(remove_dead_temporaries(dir + "/" + name), 1u);
  EXPECT_FALSE(std::filesystem::exists(dead));
  EXPECT_TRUE(std::filesystem::exists(alive));
}

TEST(Files, AReplacedFileKeepsItsPermissions) {
  const std::string file = test::scratch_dir("permissions") + "/private.vox.h5";
  ASSERT_TRUE(write_file_atomically(file, std::string_view("first")));
  ASSERT_EQ(::chmod(file.c_str(), 0600), 0);
  // Private during the write too: the temporary has the mode before its first byte.
  AtomicWrite steps;
  mode_t temporary_mode = 0;
  steps.write = [&](const std::string& temporary) -> Status {
    struct stat made {};
    if (::stat(temporary.c_str(), &made) == 0) temporary_mode = made.st_mode & 07777;
    std::ofstream(temporary, std::ios::binary) << "second";
    return Status::success();
  };
  ASSERT_TRUE(write_file_atomically(file, steps));
  EXPECT_EQ(temporary_mode, 0600u);
  struct stat info {};
  ASSERT_EQ(::stat(file.c_str(), &info), 0);
  EXPECT_EQ(info.st_mode & 07777, 0600u);
  // Set-id bits are never carried over.
  ASSERT_EQ(::chmod(file.c_str(), 06750), 0);
  ASSERT_TRUE(write_file_atomically(file, std::string_view("third")));
  ASSERT_EQ(::stat(file.c_str(), &info), 0);
  EXPECT_EQ(info.st_mode & 07777, 0750u);
  std::ifstream written(file);
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(written), {}), "third");
}

TEST(Files, AStepThatThrowsLeavesNoTemporary) {
  const std::string dir = test::scratch_dir("throwing-step");
  const std::string file = dir + "/a.vox.h5";
  ASSERT_TRUE(write_file_atomically(file, std::string_view("first")));
  for (const bool in_write : {true, false}) {
    AtomicWrite steps;
    steps.write = [&](const std::string& temporary) -> Status {
      std::ofstream(temporary, std::ios::binary) << "second";
      if (in_write) throw std::bad_alloc();
      return Status::success();
    };
    steps.before_commit = [&]() -> Status { throw std::runtime_error("check failed"); };
    EXPECT_ANY_THROW((void)write_file_atomically(file, steps));
    size_t files = 0;
    for (const auto& entry : std::filesystem::directory_iterator(dir)) {
      ++files;
      EXPECT_EQ(entry.path().filename(), "a.vox.h5");
    }
    EXPECT_EQ(files, 1u);
    std::ifstream kept(file);
    EXPECT_EQ(std::string(std::istreambuf_iterator<char>(kept), {}), "first");
  }
}

// Under AddressSanitizer or ThreadSanitizer (GCC's macros, clang's features) the allocator aborts instead of failing.
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define VOXFMT_SANITIZED_ALLOCATOR 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define VOXFMT_SANITIZED_ALLOCATOR 1
#endif
#endif
#ifndef VOXFMT_SANITIZED_ALLOCATOR
size_t address_space_bytes() {
  std::ifstream statm("/proc/self/statm");
  size_t pages = 0;
  statm >> pages;
  return pages * size_t(::sysconf(_SC_PAGESIZE));
}

TEST(Write, MemoryTheWriteCannotGetIsOutOfMemoryNotAWriteFailure) {
  // The file is built in memory before its bytes go to disk: an allocation failing there (a batch's --max-memory,
  // a container's limit) is OUT_OF_MEMORY, a limit to raise, not WRITE_FAILED, the disk; and leaves no temporary.
  const std::string dir = test::scratch_dir("write-out-of-memory");
  test::SphereSpec spec;
  spec.points = 400000;  // ~20 MB of arrays
  const Asset sphere = test::make_sphere_asset(spec);
  int out_of_memory = 0, written = 0;
  for (const size_t margin_mib : {1, 2, 4, 8, 16, 32, 256}) {
    const pid_t child = ::fork();
    ASSERT_GE(child, 0);
    if (child == 0) {
      const rlim_t limit = address_space_bytes() + (margin_mib << 20);
      const rlimit r{limit, limit};
      if (::setrlimit(RLIMIT_AS, &r) != 0) ::_exit(20);
      try {
        const Status status = write_asset(dir + "/sphere.vox.h5", sphere, test::structural());
        if (status) ::_exit(0);
        ::_exit(status.error().code == IssueCode::OutOfMemory   ? 10
                : status.error().code == IssueCode::WriteFailed ? 11
                                                                : 12);
      } catch (...) {
        ::_exit(13);
      }
    }
    int status = 0;
    ASSERT_EQ(::waitpid(child, &status, 0), child);
    ASSERT_TRUE(WIFEXITED(status)) << margin_mib << " MiB: killed by signal " << WTERMSIG(status);
    const int code = WEXITSTATUS(status);
    EXPECT_TRUE(code == 0 || code == 10) << margin_mib << " MiB more address space: exit " << code;
    out_of_memory += code == 10;
    written += code == 0;
  }
  EXPECT_GT(out_of_memory, 0);
  EXPECT_GT(written, 0);  // and with room enough, the same write succeeds
  for (const auto& entry : std::filesystem::directory_iterator(dir))
    EXPECT_EQ(entry.path().filename(), "sphere.vox.h5");
}
#endif

TEST(Text, TerminalSafeEscapesControlsAndBytesThatAreNotUtf8) {
  // Printable UTF-8 passes as it is, a multi-byte letter and a four-byte sequence included.
  EXPECT_EQ(terminal_safe("b\xC3\xA4r \xF0\x9F\x90\x87 ok"), "b\xC3\xA4r \xF0\x9F\x90\x87 ok");
  // C0, DEL and C1 (U+0085 is C2 85) are escaped byte by byte, in the case utf8_escaped writes.
  EXPECT_EQ(terminal_safe("\x1B[2J\r\n\x7F\xC2\x85."), "\\x1B[2J\\x0D\\x0A\\x7F\\xC2\\x85.");
  // U+00A0 is not a control; a raw 8-bit CSI, an overlong form and a surrogate are not UTF-8.
  EXPECT_EQ(terminal_safe("\xC2\xA0\x9B\xC0\xAF\xED\xA0\x80"), "\xC2\xA0\\x9B\\xC0\\xAF\\xED\\xA0\\x80");
  // A sequence cut short at the end of the text.
  EXPECT_EQ(terminal_safe("a\xE2\x82"), "a\\xE2\\x82");
  EXPECT_EQ(utf8_escaped("\x1B\xFF"), "\x1B\\xFF");  // utf8_escaped leaves controls alone
}

}  // namespace
}  // namespace voxfmt
