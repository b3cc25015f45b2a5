// The habits of kubectl and gh for the verbs of `esg` (docs/cli.md): `esg help [VERB]`, `esg
// version`, `esg completion bash` (the shipped deploy/completion/esg.bash), and a did-you-mean
// for a mistyped verb. They act on the command line before CLI11 parses it, from the verbs the
// app has registered, so nothing here repeats the list of verbs.
#ifndef ESG_CLIENT_VERBS_H_
#define ESG_CLIENT_VERBS_H_

#include <optional>
#include <string>
#include <vector>

#include "CLI/CLI.hpp"

namespace esg::client {

// The verb closest to `word` by edit distance, when it is at most 2 edits away (and nearer than
// the word's own length); nullopt otherwise.
std::optional<std::string> ClosestVerb(const std::string& word,
                                       const std::vector<std::string>& verbs);

// Handles `help [VERB]`, `version`, `completion bash` and an unknown verb in argv (the first
// word that is not an option or an option's value). Returns the exit status when it handled the
// command line (printing to stdout, or to stderr for an error), nullopt to let CLI11 parse it.
std::optional<int> HandleVerbHabits(const CLI::App& app, const std::vector<std::string>& args,
                                    const std::string& version_text);

}  // namespace esg::client

#endif  // ESG_CLIENT_VERBS_H_
