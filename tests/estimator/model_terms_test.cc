// The descriptors of the fixed drift terms (estimator/model_terms.h): their order and names as the
// configuration, the reports and storage use them, and the console's labels
// (console/plugin/series.js), which must name the same coefficients in the same order.
#include "estimator/model_terms.h"

#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "estimator/calibration_model.h"
#include "estimator/drift_model.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace esg::estimator {
namespace {

std::string ReadSource(const std::string& path) {
  std::ifstream in(std::string(ESG_SOURCE_DIR) + "/" + path);
  EXPECT_TRUE(in.good()) << path;
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

// Fingerprints (FNV-1a) of the frozen schema history of storage/schema.cc and
// storage/postgres_schema.cc as released, and of the frozen fields of GyroDriftModel
// (proto/esg/v1/spacecraft_config.proto).
constexpr uint64_t kSqliteFrozen = 0x4008a1848832b2a6ull;
constexpr uint64_t kPostgresFrozen = 0xbbd72b994f5f6f3bull;
constexpr uint64_t kProtoFrozen = 0x540ae03dbee0716dull;

// The terms of the table as released with the keyed form (the first 13 of theta: the schema's
// version 9 columns, the proto's frozen fields). A term added later follows them; the checks of
// the released names below hold for the released terms, the rest for every term.
constexpr int kReleasedTerms = 13;

// The coefficient of `c` a released descriptor names, by its symbol and component
// (drift_model.h); nullopt for a symbol added later.
std::optional<double> ByName(const DriftCoefficients& c, const FixedTermDescriptor& term) {
  if (term.symbol == "k0") return c.k0;
  if (term.symbol == "C1") return c.C1[term.component];
  if (term.symbol == "C2") return c.C2[term.component];
  if (term.symbol == "mu") return c.mu[term.component];
  if (term.symbol == "nu") return c.nu[term.component];
  return std::nullopt;
}

TEST(ModelTerms, ThetaIndexIsTheCoefficientTheSymbolAndComponentName) {
  for (const FixedTermDescriptor& term : kFixedTerms) {
    DriftVector theta = DriftVector::Zero();
    theta[term.theta_index] = 1.0;
    const DriftCoefficients c = DriftCoefficients::FromVector(theta);
    const std::optional<double> by_name = ByName(c, term);
    if (term.theta_index < kReleasedTerms) {
      ASSERT_TRUE(by_name.has_value()) << term.label;
      EXPECT_EQ(*by_name, 1.0) << term.label;
    }
    // Every term, a later one too: its coefficient is a member of its own, in and out of theta.
    EXPECT_EQ(c.AsVector(), theta) << term.label;
  }
}

TEST(ModelTerms, NamesAreThoseOfTheFormatsAndUnique) {
  std::set<std::string> json_names, labels, storage_keys;
  for (int i = 0; i < kNumDriftCoefficients; ++i) {
    const FixedTermDescriptor& term = kFixedTerms[i];
    EXPECT_EQ(term.theta_index, i);
    EXPECT_EQ(term.unit, "deg/h");
    EXPECT_EQ(term.frame, "k");
    EXPECT_STREQ(CoefficientName(i), FixedTermJsonName(term).c_str());
    EXPECT_TRUE(json_names.insert(FixedTermJsonName(term)).second) << FixedTermJsonName(term);
    EXPECT_TRUE(labels.insert(std::string(term.label)).second) << term.label;
    EXPECT_TRUE(storage_keys.insert(std::string(term.storage_key)).second) << term.storage_key;
  }
  EXPECT_STREQ(CoefficientName(-1), "?");
  EXPECT_STREQ(CoefficientName(kNumDriftCoefficients), "?");
  // Spot checks of the documented names (docs/formats.md, storage/records.h).
  EXPECT_EQ(FixedTermJsonName(kFixedTerms[kThetaK0]), "k0DegH");
  EXPECT_EQ(FixedTermJsonName(kFixedTerms[kThetaC1 + 2]), "c1DegH[2]");
  EXPECT_EQ(FixedTermJsonName(kFixedTerms[kThetaNu + 2]), "nuDegH[2]");
  EXPECT_EQ(FixedTermValueColumn(kFixedTerms[kThetaC2]), "c2x_deg_h");
  EXPECT_EQ(FixedTermSigmaColumn(kFixedTerms[kThetaMu + 1]), "mu23_sigma_deg_h");
  EXPECT_EQ(kFixedTerms[kThetaNu].label, "nu23");
  EXPECT_EQ(kFixedTerms[kThetaC1].label, "C11");
}

TEST(ModelTerms, FieldNamesAreTheProtoFieldsOfTheJsonKeys) {
  EXPECT_EQ(FixedTermFieldName("k0DegH"), "k0_deg_h");
  EXPECT_EQ(FixedTermFieldName("c1DegH"), "c1_deg_h");
  EXPECT_EQ(FixedTermFieldName("muDegH"), "mu_deg_h");
}

// Each JSON key once, in theta order, with its first theta index and number of components.
TEST(ModelTerms, KeysGroupTheComponentsOfATerm) {
  std::vector<std::string> keys;
  for (const FixedTermKey& key : FixedTermKeys()) {
    keys.push_back(absl::StrCat(key.json_key, " ", key.symbol, " ", key.first_theta_index, " ",
                                key.components, " ", key.unit));
  }
  // The released keys, first and in this order (a key added later follows them).
  ASSERT_GE(keys.size(), 5u);
  EXPECT_THAT(std::vector<std::string>(keys.begin(), keys.begin() + 5),
              ::testing::ElementsAre("k0DegH k0 0 0 deg/h", "c1DegH C1 1 3 deg/h",
                                     "c2DegH C2 4 3 deg/h", "muDegH mu 7 3 deg/h",
                                     "nuDegH nu 10 3 deg/h"));
  int covered = 0;
  for (const FixedTermKey& key : FixedTermKeys()) covered += std::max(1, key.components);
  EXPECT_EQ(covered, kNumDriftCoefficients);
  ASSERT_TRUE(FindFixedTermKey("c2DegH").has_value());
  EXPECT_EQ(FindFixedTermKey("c2DegH")->first_theta_index, kThetaC2);
  EXPECT_FALSE(FindFixedTermKey("c2").has_value());
}

// Model membership is the table's (calibration_model.h): "1" takes k0, mu, nu of eq. (1); "10"
// takes every term, C1 and C2 of eq. (10) too; "11" alone none.
TEST(ModelTerms, ModelStringsTakeTheTermsTheTableGivesThem) {
  // The released terms each model takes.
  auto mask = [](const char* model) {
    std::string taken;
    const auto m = ParseModel(model)->TermMask();
    for (int i = 0; i < kReleasedTerms; ++i) taken += m[i] ? '1' : '.';
    return taken;
  };
  EXPECT_EQ(mask("1"), "1......111111");
  EXPECT_EQ(mask("10"), "1111111111111");
  EXPECT_EQ(mask("10+11"), "1111111111111");
  EXPECT_EQ(mask("1+11"), "1......111111");
  EXPECT_EQ(mask("11"), ".............");
  EXPECT_FALSE(ParseModel("11")->HasFixedTerms());
  EXPECT_EQ(ParseModel("1+10")->Name(), "10");
  for (const FixedTermDescriptor& term : kFixedTerms) {
    EXPECT_NE(term.model_parts, 0u) << term.label << " is in no model";
    EXPECT_EQ(term.model_parts & ~kAllModelParts, 0u) << term.label;
    // Every term, a later one too, is taken by the models its descriptor names.
    const int i = term.theta_index;
    EXPECT_EQ(ParseModel("1")->TermMask()[i], (term.model_parts & kModelPart1) != 0) << term.label;
    EXPECT_EQ(ParseModel("10")->TermMask()[i], (term.model_parts & kModelPart10) != 0)
        << term.label;
    EXPECT_FALSE(ParseModel("11")->TermMask()[i]) << term.label;
  }
}

// The discovery frees an effect's terms as one range of theta (candidates.h FreedCoefficients).
TEST(ModelTerms, AnEffectsTermsAreContiguousInTheta) {
  std::map<std::string, std::vector<int>> by_effect;
  for (const FixedTermDescriptor& term : kFixedTerms) {
    if (!term.effect.empty()) by_effect[std::string(term.effect)].push_back(term.theta_index);
  }
  EXPECT_THAT(by_effect, ::testing::ElementsAre(::testing::Key("fourth_harmonic"),
                                                ::testing::Key("rotor_displacement"),
                                                ::testing::Key("unequal_stiffness")));
  for (const auto& [effect, indices] : by_effect) {
    for (size_t i = 1; i < indices.size(); ++i) {
      EXPECT_EQ(indices[i], indices[i - 1] + 1) << effect;
    }
  }
  EXPECT_THAT(by_effect["unequal_stiffness"], ::testing::SizeIs(6));
  EXPECT_THAT(by_effect["rotor_displacement"], ::testing::SizeIs(6));
}

// The console cannot include C++: its table of coefficients (series.js COEFFICIENTS: label, JSON
// key, component, the term's key of the keyed form, meaning; its diagnosis view reads the same
// rows) is checked against the descriptors, row for row.
TEST(ModelTerms, ConsoleLabelsAreTheDescriptorsInOrder) {
  const std::string js = ReadSource("console/plugin/series.js");
  const size_t begin = js.find("export const COEFFICIENTS = [");
  ASSERT_NE(begin, std::string::npos);
  const size_t end = js.find("].map(", begin);
  ASSERT_NE(end, std::string::npos);
  const std::string table = js.substr(begin, end - begin);
  // ['C11', 'c1DegH', 0, 'c1x', 'rotor displacement (1st harmonic)'],
  const std::regex row(R"(\['([^']*)', '([^']*)', (-?\d+), '([^']*)', '([^']*)'\])");
  std::vector<std::string> rows;
  for (std::sregex_iterator it(table.begin(), table.end(), row), done; it != done; ++it) {
    const std::smatch& m = *it;
    rows.push_back(absl::StrCat(m[1].str(), "|", m[2].str(), "|", m[3].str(), "|", m[4].str(),
                                "|", m[5].str()));
  }
  std::vector<std::string> expected;
  for (const FixedTermDescriptor& term : kFixedTerms) {
    expected.push_back(absl::StrCat(term.label, "|", term.json_key, "|", term.component, "|",
                                    term.storage_key, "|", term.meaning));
  }
  EXPECT_THAT(rows, ::testing::ElementsAreArray(expected));
}

// FNV-1a, 64 bits: a fingerprint of frozen text.
uint64_t Fingerprint(absl::string_view text) {
  uint64_t h = 14695981039346656037ull;
  for (unsigned char c : text) {
    h ^= c;
    h *= 1099511628211ull;
  }
  return h;
}

// The marks around frozen text: the schema history (the DDL of old schema versions, which
// describes what databases of those versions hold and never changes) and the proto's fields of
// the terms as released (a term added later is keyed, GyroDriftModel.coefficients).
constexpr std::pair<std::string_view, std::string_view> kFrozenMarks[] = {
    {"// Frozen schema history, begin.", "// Frozen schema history, end."},
    {"// Frozen fields, begin.", "// Frozen fields, end."}};

// The file's text without its frozen parts; each is appended to *frozen.
std::string WithoutFrozenText(const std::string& content, std::vector<std::string>* frozen) {
  std::string text = content;
  for (const auto& [begin_mark, end_mark] : kFrozenMarks) {
    std::string out;
    size_t at = 0;
    while (true) {
      const size_t begin = text.find(begin_mark, at);
      if (begin == std::string::npos) break;
      const size_t end = text.find(end_mark, begin);
      if (end == std::string::npos) {
        ADD_FAILURE() << "a frozen part without its end mark: " << begin_mark;
        break;
      }
      out += text.substr(at, begin - at);
      frozen->push_back(text.substr(begin, end + end_mark.size() - begin));
      at = end + end_mark.size();
    }
    out += text.substr(at);
    text = out;
  }
  return text;
}

// Where a fixed term is named: the production files (not tests, docs or fuzz corpora) that name
// the last term of theta, nu (eq. (1)), by any of its names: JSON key, proto field, component
// labels, theta offset, DriftCoefficients member, a string of its symbol or the model flag. A new
// fixed term is written where nu is, so these are the files a new term needs:
//   estimator/model_terms.h           its descriptor: names, unit, frame, models, effect;
//   estimator/drift_model.h, .cc      its physics: theta offset, coefficient, regressor column;
//   estimator/simulator_truth.cc      the simulator's independent printed formula for it;
//   console/plugin/series.js          the console's row (a plain module; checked above).
// Every other file reads the table (model_terms.h). Frozen text names the terms as released and
// is pinned unchanged here, so it never takes a new term: the schema history (the DDL of old
// versions in storage/schema.cc and storage/postgres_schema.cc) and GyroDriftModel's fields of
// the 13 coefficients (proto/esg/v1/spacecraft_config.proto; deprecated, read for one release:
// every coefficient is keyed on the wire, GyroDriftModel.coefficients, which proto/convert.cc
// reads and writes from the table, docs/decisions.md D107).
TEST(ModelTerms, ANewFixedTermIsWrittenInFiveFilesOnly) {
  const std::set<std::string> per_term = {
      "estimator/model_terms.h", "estimator/drift_model.h", "estimator/drift_model.cc",
      "estimator/simulator_truth.cc", "console/plugin/series.js"};
  EXPECT_LE(per_term.size(), 6u);
  const std::regex names(
      R"(nuDegH|nu_deg_h|nu23|nu31|nu12|kThetaNu|kCoefficientNu|\.nu\b|mu_nu|"nu"|'nu')");
  const std::filesystem::path root(ESG_SOURCE_DIR);
  std::set<std::string> found;
  std::map<std::string, std::vector<uint64_t>> frozen_parts;
  for (const char* dir : {"estimator", "proto", "storage", "server", "client", "console/plugin",
                          "console/gateway", "fuzz"}) {
    for (const auto& entry : std::filesystem::recursive_directory_iterator(root / dir)) {
      const std::string ext = entry.path().extension().string();
      if (!entry.is_regular_file() ||
          (ext != ".h" && ext != ".cc" && ext != ".proto" && ext != ".js")) {
        continue;
      }
      const std::string path = std::filesystem::relative(entry.path(), root).generic_string();
      std::vector<std::string> frozen;
      const std::string content = WithoutFrozenText(ReadSource(path), &frozen);
      for (const std::string& part : frozen) frozen_parts[path].push_back(Fingerprint(part));
      if (std::regex_search(content, names)) found.insert(path);
    }
  }
  EXPECT_THAT(found, ::testing::ContainerEq(per_term));
  // The proto's frozen fields are the release before's form: one deprecated field per JSON key of
  // the table as released, in order, none written (a field not deprecated would be a second form
  // to write a term in); a key added to the table later has no field of its own (it is keyed).
  std::vector<std::string> proto_frozen;
  WithoutFrozenText(ReadSource("proto/esg/v1/spacecraft_config.proto"), &proto_frozen);
  ASSERT_EQ(proto_frozen.size(), 1u);
  const std::regex field(R"((double|repeated double) (\w+) = \d+( \[deprecated = true\])?;)");
  std::vector<std::string> fields, deprecated;
  for (std::sregex_iterator it(proto_frozen[0].begin(), proto_frozen[0].end(), field), done;
       it != done; ++it) {
    fields.push_back((*it)[2].str());
    if ((*it)[3].matched) deprecated.push_back((*it)[2].str());
  }
  ASSERT_LE(fields.size(), FixedTermKeys().size());
  std::vector<std::string> released_keys;
  for (size_t i = 0; i < fields.size(); ++i) {
    released_keys.push_back(FixedTermFieldName(FixedTermKeys()[i].json_key));
  }
  EXPECT_THAT(fields, ::testing::ElementsAreArray(released_keys));
  EXPECT_EQ(deprecated, fields);
  // The frozen parts, as released: version 1-9's DDL and coefficient columns (SQLite), version
  // 7's DDL (PostgreSQL): a change here changes what an old database is taken to be; the proto's
  // fields of the 13 coefficients: a change here changes the wire.
  EXPECT_THAT(frozen_parts,
              ::testing::UnorderedElementsAre(
                  ::testing::Pair("storage/schema.cc", ::testing::ElementsAre(kSqliteFrozen)),
                  ::testing::Pair("storage/postgres_schema.cc",
                                  ::testing::ElementsAre(kPostgresFrozen)),
                  ::testing::Pair("proto/esg/v1/spacecraft_config.proto",
                                  ::testing::ElementsAre(kProtoFrozen))));
}

}  // namespace
}  // namespace esg::estimator
