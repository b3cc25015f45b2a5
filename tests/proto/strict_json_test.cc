// Tests of proto/strict_json (a key repeated in an object, an array inside an array, named by
// their JSON path) and of the configuration reader that runs it first (docs/formats.md,
// "Spacecraft configuration JSON", "Validation"): protobuf's parser alone keeps one value of a
// repeated key and reads [5, 5, [[[[30]]]]] as [5, 5, 30].
#include "proto/strict_json.h"

#include <string>

#include "absl/strings/str_replace.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "proto/convert.h"
#include "tests/testing/status_matchers.h"

namespace esg::proto_convert {
namespace {

using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::AllOf;
using ::testing::HasSubstr;
using ::testing::StartsWith;

constexpr absl::StatusCode kInvalid = absl::StatusCode::kInvalidArgument;

TEST(StrictJson, AcceptsOrdinaryJsonAndTheSameKeyInDifferentObjects) {
  EXPECT_THAT(CheckStrictJson(R"({"a": {"id": 1}, "b": [{"id": 2}, {"id": 3}], "c": [1, 2]})"),
              IsOk());
  EXPECT_THAT(CheckStrictJson("[]"), IsOk());
  EXPECT_THAT(CheckStrictJson("3.5"), IsOk());
}

TEST(StrictJson, RefusesADuplicateKeyNamingItsPath) {
  const absl::Status s =
      CheckStrictJson(R"({"gyros": [{"id": 1}, {"id": 2, "azimuthDeg": 3, "azimuthDeg": 4}]})");
  EXPECT_THAT(s, StatusIs(kInvalid, StartsWith("gyros[1].azimuthDeg: duplicate key")));
  EXPECT_THAT(CheckStrictJson(R"({"spacecraftId": "A", "x": {}, "spacecraftId": "B"})"),
              StatusIs(kInvalid, StartsWith("spacecraftId: duplicate key")));
}

TEST(StrictJson, ComparesKeysAfterUnescaping) {
  EXPECT_THAT(CheckStrictJson(R"({"id": 1, "\u0069d": 2})"),
              StatusIs(kInvalid, StartsWith("id: duplicate key")));
}

TEST(StrictJson, RefusesAnArrayInsideAnArrayNamingTheOuterArray) {
  EXPECT_THAT(CheckStrictJson(R"({"gyros": [{"readoutDistortion": [5, 5, [[[[30]]]]]}]})"),
              StatusIs(kInvalid, StartsWith("gyros[0].readoutDistortion: an array inside an "
                                            "array (element 2)")));
  EXPECT_THAT(CheckStrictJson("[[1]]"),
              StatusIs(kInvalid, StartsWith("an array inside an array (element 0)")));
}

TEST(StrictJson, AllowsNestedArraysOnlyWhenAsked) {
  StrictJsonOptions options;
  options.allow_nested_arrays = true;
  EXPECT_THAT(CheckStrictJson(R"({"m": [[1, 2], [3, 4]]})", options), IsOk());
  EXPECT_THAT(CheckStrictJson(R"({"m": [[{"k": 1, "k": 2}]]})", options),
              StatusIs(kInvalid, StartsWith("m[0][0].k: duplicate key")));
}

TEST(StrictJson, MalformedJsonSaysWhere) {
  EXPECT_THAT(CheckStrictJson(R"({"a": 1,)"),
              StatusIs(kInvalid, AllOf(StartsWith("not valid JSON: "), HasSubstr("line 1"))));
  EXPECT_THAT(CheckStrictJson(R"({"a": 1} x)"), StatusIs(kInvalid, StartsWith("not valid JSON")));
}

// A valid configuration (the example of docs/formats.md, shortened), and the same with one defect.
std::string ExampleConfig() {
  return R"json({
  "spacecraftId": "RDK-1",
  "gyros": [
    {"id": 1, "caseToBody": [1, 0, 0,  0, 1, 0,  0, 0, 1], "model": {"k0DegH": 0.25}},
    {"id": 2, "caseToBody": [0, 0, 1,  0, 1, 0,  -1, 0, 0], "model": {"k0DegH": 0.31}},
    {"id": 3, "caseToBody": [0, -1, 0,  1, 0, 0,  0, 0, 1], "model": {"k0DegH": 0.22}}
  ],
  "workingPair": [1, 2],
  "reservePair": [1, 3],
  "starTracker": {"noiseArcsec": [5, 5, 30]}
})json";
}

std::string ExampleConfigWith(absl::string_view from, absl::string_view to) {
  const std::string json = ExampleConfig();
  const std::string out = absl::StrReplaceAll(json, {{from, to}});
  EXPECT_NE(out, json) << from;
  return out;
}

TEST(ConfigJsonStrict, ExampleIsRead) { EXPECT_THAT(ParseConfigJson(ExampleConfig()), IsOk()); }

TEST(ConfigJsonStrict, DuplicateKeyIsRefusedNotResolvedSilently) {
  // Without the check, protobuf's parser reads gyro 2's k0 as 0.5 (the last value).
  EXPECT_THAT(ParseConfigJson(ExampleConfigWith(R"("model": {"k0DegH": 0.31})",
                                                R"("model": {"k0DegH": 0.31, "k0DegH": 0.5})")),
              StatusIs(kInvalid, StartsWith("gyros[1].model.k0DegH: duplicate key")));
  EXPECT_THAT(ParseConfigJson(ExampleConfigWith(R"("workingPair": [1, 2],)",
                                                R"("workingPair": [1, 2], "workingPair": [2, 3],)")),
              StatusIs(kInvalid, StartsWith("workingPair: duplicate key")));
}

TEST(ConfigJsonStrict, NestedArrayIsRefusedNotFlattened) {
  // Without the check, protobuf's parser reads this noise as [5, 5, 30].
  EXPECT_THAT(ParseConfigJson(ExampleConfigWith("[5, 5, 30]", "[5, 5, [[[[30]]]]]")),
              StatusIs(kInvalid,
                       StartsWith("starTracker.noiseArcsec: an array inside an array (element 2)")));
  EXPECT_THAT(ParseConfigJson(ExampleConfigWith(
                  R"("model": {"k0DegH": 0.22})",
                  R"("model": {"k0DegH": 0.22}, "readoutDistortion": [[0, 0, 0], [0, 0, 0], [0, 0, 0]])")),
              StatusIs(kInvalid,
                       StartsWith("gyros[2].readoutDistortion: an array inside an array (element 0)")));
}

TEST(ConfigJsonStrict, MalformedJsonIsNamedAsTheConfiguration) {
  EXPECT_THAT(ParseConfigJson(ExampleConfigWith(R"("workingPair": [1, 2],)", R"("workingPair" [1, 2],)")),
              StatusIs(kInvalid, StartsWith("config JSON: not valid JSON")));
}

}  // namespace
}  // namespace esg::proto_convert
