// A real small file system for tests of a full or read-only disk: a tmpfs mounted on a new
// directory of a TempDir (root in a container may mount one; where it is refused, ok() is false
// with the reason, and the test skips saying so).
#ifndef ESG_TESTS_TESTING_TMPFS_H_
#define ESG_TESTS_TESTING_TMPFS_H_

#include <sys/mount.h>

#include <cerrno>
#include <filesystem>
#include <string>
#include <system_error>

#include "absl/strings/str_cat.h"
#include "tests/testing/temp_dir.h"

namespace esg::testing {

// A tmpfs of `size` mounted on a new directory of `dir` for its lifetime (unmounted, lazily if
// busy, at destruction); ok() is false, with the reason, where mounting is refused.
class Tmpfs {
 public:
  Tmpfs(const TempDir& dir, const std::string& size) : path_(dir.File("mnt")) {
    std::filesystem::create_directory(path_);
    const std::string data = "size=" + size + ",mode=0755";
    if (::mount("tmpfs", path_.c_str(), "tmpfs", 0, data.c_str()) == 0) {
      mounted_ = true;
    } else {
      error_ = absl::StrCat("mount -t tmpfs -o ", data, " tmpfs ", path_, ": ", std::error_code(errno, std::generic_category()).message());
    }
  }
  ~Tmpfs() {
    if (mounted_ && ::umount(path_.c_str()) != 0) ::umount2(path_.c_str(), MNT_DETACH);
  }
  Tmpfs(const Tmpfs&) = delete;
  Tmpfs& operator=(const Tmpfs&) = delete;

  bool ok() const { return mounted_; }
  const std::string& error() const { return error_; }
  std::string File(const std::string& name) const { return path_ + "/" + name; }
  // Remounts read-only; the reason if refused.
  std::string RemountReadOnly() {
    if (::mount(nullptr, path_.c_str(), nullptr, MS_REMOUNT | MS_RDONLY, nullptr) == 0) return "";
    return absl::StrCat("mount -o remount,ro ", path_, ": ", std::error_code(errno, std::generic_category()).message());
  }

 private:
  std::string path_;
  bool mounted_ = false;
  std::string error_;
};

}  // namespace esg::testing

#endif  // ESG_TESTS_TESTING_TMPFS_H_
