// Every kind of broken file is refused with its own code and a message naming the file and the object.
#include <gtest/gtest.h>
#include <hdf5.h>

#include <filesystem>
#include <fstream>
#include <functional>

#include "test_support.h"
#include "voxfmt/io.h"

namespace voxfmt {
namespace {

class Malformed : public ::testing::Test {
 protected:
  void SetUp() override {
    H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
    dir_ = test::scratch_dir(::testing::UnitTest::GetInstance()->current_test_info()->name());
    file_ = dir_ + "/asset.vox.h5";
    ASSERT_TRUE(write_asset(file_, test::make_full_asset(), test::structural()));
  }
  // Opens the valid file read-write and lets `change` break one thing.
  void mutate(const std::function<void(hid_t)>& change) {
    hid_t f = H5Fopen(file_.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
    ASSERT_GE(f, 0);
    change(f);
    H5Fclose(f);
  }
  void expect_refused(IssueCode code, const std::string& path_fragment) {
    Result<Asset> r = read_asset(file_, nullptr, test::structural_read());
    ASSERT_FALSE(r) << "expected " << code_name(code);
    EXPECT_EQ(code_name(r.error().code), std::string(code_name(code))) << r.error().message;
    EXPECT_NE(r.error().message.find(file_), std::string::npos) << r.error().message;
    EXPECT_NE(r.error().message.find(path_fragment), std::string::npos) << r.error().message;
    // validate_file reports the same finding.
    bool found = false;
    for (const Issue& issue : validate_file(file_)) found |= issue.code == code;
    EXPECT_TRUE(found);
  }
  // Replaces dataset `path` by an (unwritten) one of another file type or shape.
  static void replace_dataset(hid_t f, const char* path, hid_t file_type, std::vector<hsize_t> dims) {
    H5Ldelete(f, path, H5P_DEFAULT);
    hid_t s = H5Screate_simple(int(dims.size()), dims.data(), nullptr);
    hid_t d = H5Dcreate2(f, path, file_type, s, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    H5Dclose(d);
    H5Sclose(s);
  }
  static void write_u32(hid_t f, const char* path, std::vector<uint32_t> values) {
    hid_t d = H5Dopen2(f, path, H5P_DEFAULT);
    ASSERT_GE(H5Dwrite(d, H5T_NATIVE_UINT32, H5S_ALL, H5S_ALL, H5P_DEFAULT, values.data()), 0);
    H5Dclose(d);
  }
  std::string dir_, file_;
};

TEST_F(Malformed, NotHdf5) {
  std::ofstream(file_) << "solid bunny\nendsolid\n";
  expect_refused(IssueCode::NotHdf5, "not an HDF5 file");
}

TEST_F(Malformed, Truncated) {
  std::filesystem::resize_file(file_, std::filesystem::file_size(file_) / 2);
  Result<Asset> r = read_asset(file_, nullptr, test::structural_read());
  ASSERT_FALSE(r);
  EXPECT_TRUE(r.error().code == IssueCode::NotHdf5 || r.error().code == IssueCode::ReadFailed) << r.error().message;
  EXPECT_NE(r.error().message.find(file_), std::string::npos);
}

TEST_F(Malformed, MissingFile) {
  Result<Asset> r = read_asset(dir_ + "/nope.vox.h5");
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, IssueCode::FileNotFound);
}

TEST_F(Malformed, MissingDataset) {
  mutate([](hid_t f) { H5Ldelete(f, "/pointshell/normals", H5P_DEFAULT); });
  expect_refused(IssueCode::MissingObject, "/pointshell/normals");
}

TEST_F(Malformed, WrongDtype) {
  mutate([](hid_t f) { replace_dataset(f, "/voxelmap/bricks", H5T_IEEE_F32LE, {1, 2, 2}); });
  expect_refused(IssueCode::WrongDtype, "/voxelmap/bricks");
}

TEST_F(Malformed, BrickTableEntryOutOfRange) {
  mutate([](hid_t f) {
    hid_t d = H5Dopen2(f, "/voxelmap/bricks", H5P_DEFAULT);
    const int32_t entries[4] = {0, -1, -3, 1};  // -3 is neither a value brick nor a coarse side
    ASSERT_GE(H5Dwrite(d, H5T_NATIVE_INT32, H5S_ALL, H5S_ALL, H5P_DEFAULT, entries), 0);
    H5Dclose(d);
  });
  expect_refused(IssueCode::ValueOutOfRange, "/voxelmap/bricks");
}

TEST_F(Malformed, WrongShape) {
  mutate([](hid_t f) { replace_dataset(f, "/pointshell/points", H5T_IEEE_F64LE, {7, 2}); });
  expect_refused(IssueCode::WrongShape, "/pointshell/points");
}

TEST_F(Malformed, ChildIndexOutOfRange) {
  mutate([](hid_t f) { write_u32(f, "/pointshell/child_begin", {1, 4, 6, 1000000, 7, 7, 7}); });
  expect_refused(IssueCode::ChildRangeInvalid, "/pointshell/child_begin");
}

TEST_F(Malformed, ChildrenNotBreadthFirst) {
  // Node 1 claims node 6 and node 3 claims nodes 4..5: in range, but not in level order.
  mutate([](hid_t f) {
    write_u32(f, "/pointshell/child_begin", {1, 6, 7, 4, 7, 7, 7});
    write_u32(f, "/pointshell/child_count", {3, 1, 0, 2, 0, 0, 0});
  });
  expect_refused(IssueCode::TreeNotBreadthFirst, "/pointshell/child_begin");
}

// The grid must cover the object (spec §3): a moved origin or blown-up bounds are consistent numbers engines
// cannot use (MuJoCo meshes nothing, a query finds no contact).
TEST_F(Malformed, GridMovedOffItsObject) {
  auto shift = [](hid_t f, const char* object, const char* name, double by) {
    hid_t o = H5Oopen(f, object, H5P_DEFAULT);  // (HDF5 1.10 cannot write one opened by name from the file)
    hid_t a = H5Aopen(o, name, H5P_DEFAULT);
    ASSERT_GE(a, 0);
    double v[3];
    ASSERT_GE(H5Aread(a, H5T_NATIVE_DOUBLE, v), 0);
    v[0] += by;
    ASSERT_GE(H5Awrite(a, H5T_NATIVE_DOUBLE, v), 0);
    H5Aclose(a);
    H5Oclose(o);
  };
  mutate([&](hid_t f) { shift(f, "/voxelmap", "origin", 5.0); });
  expect_refused(IssueCode::ValueOutOfRange, "voxelmap's grid");
  ASSERT_TRUE(write_asset(file_, test::make_full_asset(), test::structural()));
  mutate([&](hid_t f) { shift(f, "/", "bounds_max", 1e6); });
  expect_refused(IssueCode::ValueOutOfRange, "/@bounds_min");
}

TEST_F(Malformed, PointOutsideTheGrid) {
  mutate([](hid_t f) {
    hid_t d = H5Dopen2(f, "/pointshell/points", H5P_DEFAULT);
    hid_t space = H5Dget_space(d);
    std::vector<double> points(size_t(H5Sget_simple_extent_npoints(space)));
    ASSERT_GE(H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, points.data()), 0);
    points[3 * 2 + 1] = 1e3;  // point 2, y
    ASSERT_GE(H5Dwrite(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, points.data()), 0);
    H5Sclose(space);
    H5Dclose(d);
  });
  expect_refused(IssueCode::ValueOutOfRange, "/pointshell/points");
}

TEST_F(Malformed, UnknownMajorVersion) {
  mutate([](hid_t f) {
    hid_t a = H5Aopen(f, "format_version", H5P_DEFAULT);
    const uint32_t v[2] = {3, 0};
    H5Awrite(a, H5T_NATIVE_UINT32, v);
    H5Aclose(a);
  });
  expect_refused(IssueCode::VersionUnsupported, "format version 3.0");
}

TEST_F(Malformed, NewerMinorVersionIsReadWithAWarning) {
  mutate([](hid_t f) {
    hid_t a = H5Aopen(f, "format_version", H5P_DEFAULT);
    const uint32_t v[2] = {2, 3};
    H5Awrite(a, H5T_NATIVE_UINT32, v);
    H5Aclose(a);
    hid_t g = H5Gcreate2(f, "/from_the_future", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    H5Gclose(g);
  });
  std::vector<Issue> warnings;
  Result<Asset> r = read_asset(file_, &warnings, test::structural_read());
  ASSERT_TRUE(r) << r.error().message;
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_EQ(warnings[0].code, IssueCode::VersionNewerMinor);
  bool unknown_reported = false;
  for (const Issue& issue : validate_file(file_))
    unknown_reported |= issue.code == IssueCode::UnknownObject && issue.path == "/from_the_future";
  EXPECT_TRUE(unknown_reported);
}

}  // namespace
}  // namespace voxfmt
