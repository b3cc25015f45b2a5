// The name an alert acknowledgement is recorded under (docs/service.md "Security": the identity
// model). With a tokens file it is the caller's token name; without one the caller gives it, and
// it is shown on consoles and in logs, so it is bounded and holds no character that hides or
// reorders text.
#ifndef ESG_SERVER_OPERATOR_NAME_H_
#define ESG_SERVER_OPERATOR_NAME_H_

#include "absl/status/status.h"
#include "absl/strings/string_view.h"

namespace esg::server {

// Longest operator name [Unicode characters].
inline constexpr int kMaxOperatorNameCharacters = 64;

// OK for 1 to kMaxOperatorNameCharacters characters of valid UTF-8 without control characters
// (U+0000-U+001F, U+007F-U+009F), bidirectional formatting characters (U+061C, U+200E, U+200F,
// U+202A-U+202E, U+2066-U+2069), invisible separators (U+200B-U+200D, U+2060, U+FEFF) or
// line/paragraph separators (U+2028, U+2029). InvalidArgument "<field>: ..." otherwise; the
// message quotes at most the first 32 bytes of the name, escaped.
absl::Status ValidateOperatorName(absl::string_view name, absl::string_view field);

}  // namespace esg::server

#endif  // ESG_SERVER_OPERATOR_NAME_H_
