#include "server/operator_name.h"

#include <cstdint>
#include <optional>

#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace esg::server {
namespace {

// The name's head, escaped, for a message: the name itself may be what is unfit to print.
std::string Quoted(absl::string_view name) {
  constexpr size_t kQuoteBytes = 32;
  return absl::StrCat("\"", absl::CHexEscape(name.substr(0, kQuoteBytes)),
                      name.size() > kQuoteBytes ? "\"..." : "\"");
}

// The code point starting at name[*i], advancing *i; nullopt for invalid UTF-8 (a stray or
// missing continuation byte, an overlong form, a surrogate, beyond U+10FFFF).
std::optional<char32_t> NextCodePoint(absl::string_view name, size_t* i) {
  const auto byte = [&](size_t k) { return static_cast<unsigned char>(name[k]); };
  const unsigned char lead = byte(*i);
  int length = 0;
  char32_t cp = 0;
  char32_t smallest = 0;
  if (lead < 0x80) {
    ++*i;
    return lead;
  } else if ((lead & 0xE0) == 0xC0) {
    length = 2, cp = lead & 0x1F, smallest = 0x80;
  } else if ((lead & 0xF0) == 0xE0) {
    length = 3, cp = lead & 0x0F, smallest = 0x800;
  } else if ((lead & 0xF8) == 0xF0) {
    length = 4, cp = lead & 0x07, smallest = 0x10000;
  } else {
    return std::nullopt;
  }
  if (*i + length > name.size()) return std::nullopt;
  for (int k = 1; k < length; ++k) {
    if ((byte(*i + k) & 0xC0) != 0x80) return std::nullopt;
    cp = (cp << 6) | (byte(*i + k) & 0x3F);
  }
  if (cp < smallest || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) return std::nullopt;
  *i += length;
  return cp;
}

// Characters that hide, reorder or break the text around them on a console or in a log line.
bool Unprintable(char32_t cp) {
  return cp < 0x20 || (cp >= 0x7F && cp <= 0x9F) || cp == 0x061C || cp == 0x200E || cp == 0x200F ||
         (cp >= 0x202A && cp <= 0x202E) || (cp >= 0x2066 && cp <= 0x2069) ||
         (cp >= 0x200B && cp <= 0x200D) || cp == 0x2060 || cp == 0xFEFF || cp == 0x2028 ||
         cp == 0x2029;
}

}  // namespace

absl::Status ValidateOperatorName(absl::string_view name, absl::string_view field) {
  if (name.empty()) return absl::InvalidArgumentError(absl::StrCat(field, ": must not be empty"));
  int characters = 0;
  size_t i = 0;
  while (i < name.size()) {
    const size_t at = i;
    const std::optional<char32_t> cp = NextCodePoint(name, &i);
    if (!cp.has_value()) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: %s is not valid UTF-8 (at byte %d)", field, Quoted(name), at));
    }
    if (Unprintable(*cp)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: %s holds U+%04X at byte %d, a control, invisible or bidirectional formatting "
          "character",
          field, Quoted(name), static_cast<uint32_t>(*cp), at));
    }
    if (++characters > kMaxOperatorNameCharacters) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: %s is longer than %d characters (%d bytes)", field, Quoted(name),
                          kMaxOperatorNameCharacters, name.size()));
    }
  }
  return absl::OkStatus();
}

}  // namespace esg::server
