#include "client/verbs.h"

#include <algorithm>
#include <cstdio>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_replace.h"
#include "client/bash_completion.h"

namespace esg::client {
namespace {

// Levenshtein distance (insertions, deletions, substitutions).
int EditDistance(const std::string& a, const std::string& b) {
  std::vector<int> row(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) row[j] = static_cast<int>(j);
  for (size_t i = 1; i <= a.size(); ++i) {
    int diagonal = row[0];
    row[0] = static_cast<int>(i);
    for (size_t j = 1; j <= b.size(); ++j) {
      const int above = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = above;
    }
  }
  return row[b.size()];
}

// The verbs a user is offered: not the hidden ones (no group: `esg __complete`).
std::vector<std::string> VerbNames(const CLI::App& app) {
  std::vector<std::string> names;
  for (const CLI::App* sub : app.get_subcommands([](const CLI::App*) { return true; })) {
    if (sub->get_group().empty()) continue;
    names.push_back(sub->get_name());
  }
  return names;
}

const CLI::App* FindVerb(const CLI::App& app, const std::string& name) {
  for (const CLI::App* sub : app.get_subcommands([](const CLI::App*) { return true; })) {
    if (sub->get_name() == name) return sub;
  }
  return nullptr;
}

// The positional words of the command line: what is not an option or the value of one of the
// root's options that take a value (--server ADDR, --token TOKEN, ...).
std::vector<std::string> Words(const CLI::App& app, const std::vector<std::string>& args) {
  std::vector<std::string> words;
  for (size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    if (a == "--") break;
    if (absl::StartsWith(a, "-")) {
      if (absl::StrContains(a, "=")) continue;
      for (const CLI::Option* option : app.get_options()) {
        if (option->get_type_size() != 0 && option->check_name(a)) {
          ++i;  // its value
          break;
        }
      }
      continue;
    }
    words.push_back(a);
  }
  return words;
}

int UnknownVerb(const CLI::App& app, const std::string& word, const std::string& context) {
  const std::optional<std::string> near = ClosestVerb(word, VerbNames(app));
  std::fprintf(stderr, "esg: %sunknown verb '%s'%s (esg help lists the verbs)\n", context.c_str(),
               word.c_str(), near ? absl::StrCat("; did you mean '", *near, "'?").c_str() : "");
  return 2;
}

}  // namespace

std::optional<std::string> ClosestVerb(const std::string& word,
                                       const std::vector<std::string>& verbs) {
  std::optional<std::string> best;
  int best_distance = 3;  // at most 2 edits
  for (const std::string& verb : verbs) {
    const int d = EditDistance(word, verb);
    if (d < best_distance && d < static_cast<int>(word.size())) {
      best_distance = d;
      best = verb;
    }
  }
  return best;
}

std::optional<int> HandleVerbHabits(const CLI::App& app, const std::vector<std::string>& args,
                                    const std::string& version_text) {
  const std::vector<std::string> words = Words(app, args);
  if (words.empty()) return std::nullopt;  // CLI11 says a verb is required
  const std::string& verb = words[0];
  if (verb == "help") {
    if (words.size() < 2) {
      // The root has no name before parsing: "esg" as the program, without the name's space.
      std::fputs(absl::StrReplaceAll(app.help("esg"), {{"Usage: esg  ", "Usage: esg "}}).c_str(),
                 stdout);
      return 0;
    }
    const CLI::App* sub = FindVerb(app, words[1]);
    if (sub == nullptr) return UnknownVerb(app, words[1], "help: ");
    std::fputs(sub->help("esg").c_str(), stdout);
    return 0;
  }
  if (verb == "version") {
    std::printf("%s\n", version_text.c_str());
    return 0;
  }
  if (verb == "completion") {
    if (words.size() >= 2 && words[1] == "bash") {
      std::fputs(kBashCompletionScript, stdout);
      return 0;
    }
    std::fprintf(stderr, "esg: completion: expected `esg completion bash`%s\n",
                 words.size() >= 2 ? absl::StrCat(" (no completion for '", words[1], "')").c_str()
                                   : "");
    return 2;
  }
  if (FindVerb(app, verb) == nullptr) return UnknownVerb(app, verb, "");
  return std::nullopt;
}

}  // namespace esg::client
