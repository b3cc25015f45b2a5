// Strict JSON check (strict_json.h): nlohmann-json's SAX parser with a handler that tracks the
// JSON path and the keys of every open object.
#include "proto/strict_json.h"

#include <cstddef>
#include <set>
#include <string>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "nlohmann/json.hpp"

namespace esg::proto_convert {
namespace {

using Json = nlohmann::json;

class StrictHandler : public nlohmann::json_sax<Json> {
 public:
  explicit StrictHandler(const StrictJsonOptions& options) : options_(options) {}

  const absl::Status& status() const { return status_; }

  bool null() override { return Scalar(); }
  bool boolean(bool) override { return Scalar(); }
  bool number_integer(number_integer_t) override { return Scalar(); }
  bool number_unsigned(number_unsigned_t) override { return Scalar(); }
  bool number_float(number_float_t, const string_t&) override { return Scalar(); }
  bool string(string_t&) override { return Scalar(); }
  bool binary(binary_t&) override { return Scalar(); }

  bool start_object(std::size_t) override {
    open_.push_back(Container{false, ChildPath(), {}, {}, 0});
    return true;
  }
  bool key(string_t& key) override {
    Container& object = open_.back();
    if (!object.keys.insert(key).second) {
      return Fail(Located(Member(object.path, key),
                          "duplicate key (a key may appear once in an object)"));
    }
    object.key = key;
    return true;
  }
  bool end_object() override { return Close(); }

  bool start_array(std::size_t) override {
    if (!open_.empty() && open_.back().is_array && !options_.allow_nested_arrays) {
      return Fail(Located(open_.back().path,
                          absl::StrCat("an array inside an array (element ", open_.back().index,
                                       ")")));
    }
    open_.push_back(Container{true, ChildPath(), {}, {}, 0});
    return true;
  }
  bool end_array() override { return Close(); }

  bool parse_error(std::size_t, const std::string&,
                   const nlohmann::detail::exception& error) override {
    // "[json.exception.parse_error.101] parse error at line 1, column 5: ..." without the id.
    std::string what = error.what();
    if (absl::StartsWith(what, "[json.exception.")) {
      const size_t close = what.find("] ");
      if (close != std::string::npos) what = what.substr(close + 2);
    }
    return Fail(absl::StrCat("not valid JSON: ", what));
  }

 private:
  struct Container {
    bool is_array = false;
    std::string path;            // JSON path of this object or array ("" for the root)
    std::set<std::string> keys;  // an object's keys so far
    std::string key;             // an object's current key
    size_t index = 0;            // an array's current element
  };

  static std::string Member(const std::string& path, const std::string& key) {
    return path.empty() ? key : absl::StrCat(path, ".", key);
  }
  static std::string Located(const std::string& path, const std::string& reason) {
    return path.empty() ? reason : absl::StrCat(path, ": ", reason);
  }

  // The path of the value that starts now.
  std::string ChildPath() const {
    if (open_.empty()) return std::string();
    const Container& parent = open_.back();
    return parent.is_array ? absl::StrCat(parent.path, "[", parent.index, "]")
                           : Member(parent.path, parent.key);
  }
  // A value of the innermost container has ended.
  void ValueEnded() {
    if (!open_.empty() && open_.back().is_array) ++open_.back().index;
  }
  bool Scalar() {
    ValueEnded();
    return true;
  }
  bool Close() {
    open_.pop_back();
    ValueEnded();
    return true;
  }
  bool Fail(std::string message) {
    status_ = absl::InvalidArgumentError(std::move(message));
    return false;
  }

  const StrictJsonOptions options_;
  std::vector<Container> open_;
  absl::Status status_;
};

}  // namespace

absl::Status CheckStrictJson(std::string_view text, const StrictJsonOptions& options) {
  StrictHandler handler(options);
  const bool ok = Json::sax_parse(text.begin(), text.end(), &handler);
  if (!ok && handler.status().ok()) return absl::InvalidArgumentError("not valid JSON");
  return handler.status();
}

}  // namespace esg::proto_convert
