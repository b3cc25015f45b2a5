// Fuzz target: the bearer-token file parser (server::TokenAuthorizer::Parse).
// Property: a file is refused with InvalidArgument "fuzz:<line>: <reason>" (or "fuzz: no tokens")
// whose message contains no token, nor any other word of the file long enough to be one (a token
// written in the wrong column is still a secret); an accepted file holds exactly one token per
// line that is neither blank nor a comment.
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_split.h"
#include "fuzz/fuzz_util.h"
#include "server/auth.h"

namespace {

// Words this long could be a token; the parser's own message texts have none.
constexpr size_t kSecretLength = 12;

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace esg;
  const absl::string_view text = fuzz::AsAbslText(data, size);
  absl::StatusOr<server::TokenAuthorizer> auth = server::TokenAuthorizer::Parse(text, "fuzz");
  int token_lines = 0;
  std::vector<absl::string_view> secrets;
  for (absl::string_view raw : absl::StrSplit(text, '\n')) {
    const absl::string_view line = absl::StripAsciiWhitespace(raw);
    if (line.empty() || line.front() == '#') continue;
    ++token_lines;
    for (absl::string_view word : absl::StrSplit(line, absl::ByAnyChar(" \t"), absl::SkipEmpty())) {
      if (word.size() >= kSecretLength) secrets.push_back(word);
    }
  }
  if (!auth.ok()) {
    fuzz::CheckCleanError(auth.status(), absl::StatusCode::kInvalidArgument);
    const absl::string_view message = auth.status().message();
    ESG_FUZZ_CHECK(absl::StartsWith(message, "fuzz:"), std::string(message));
    for (absl::string_view secret : secrets) {
      ESG_FUZZ_CHECK(!absl::StrContains(message, secret),
                     "a word of the file (a possible token) is in the message");
    }
    return 0;
  }
  ESG_FUZZ_CHECK(auth->size() == token_lines, "one token per line");
  return 0;
}
