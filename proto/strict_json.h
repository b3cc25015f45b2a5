// Strict reading of a user's JSON file before it is interpreted (docs/formats.md, "Spacecraft
// configuration JSON", "Validation"): refuses what the JSON parsers this project uses accept
// silently. Both nlohmann-json and protobuf's JSON parser keep one value of a key repeated in an
// object; protobuf's parser also flattens an array inside a repeated field (`[5, 5, [[30]]]` is read
// as `[5, 5, 30]`).
#ifndef ESG_PROTO_STRICT_JSON_H_
#define ESG_PROTO_STRICT_JSON_H_

#include <string_view>

#include "absl/status/status.h"

namespace esg::proto_convert {

struct StrictJsonOptions {
  // An array directly inside an array is refused unless set. No field of the spacecraft
  // configuration holds one (esg.v1.SpacecraftConfig has no google.protobuf.ListValue, Value or
  // Struct), so the configuration reader leaves it false.
  bool allow_nested_arrays = false;
};

// OK when `text` is one JSON value in which no object repeats a key (compared exactly, after
// unescaping) and, unless options.allow_nested_arrays, no array holds an array. Otherwise
// InvalidArgument, whose message starts with the JSON path (`gyros[1].model` style, the key as
// written; the root is the empty path):
//   "gyros[1].azimuthDeg: duplicate key (a key may appear once in an object)"
//   "gyros[0].readoutDistortion: an array inside an array (element 2)"
//   "not valid JSON: parse error at line 3, column 7: ..." for text that is not JSON.
// Callers prefix the message with what they read ("config JSON", "mapping", the file).
absl::Status CheckStrictJson(std::string_view text, const StrictJsonOptions& options = {});

}  // namespace esg::proto_convert

#endif  // ESG_PROTO_STRICT_JSON_H_
