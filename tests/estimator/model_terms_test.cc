// The descriptors of the fixed drift terms (estimator/model_terms.h): their order and names as the
// configuration, the reports and storage use them, and the console's labels
// (console/plugin/series.js), which must name the same coefficients in the same order.
#include "estimator/model_terms.h"

#include <filesystem>
#include <fstream>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "estimator/calibration_model.h"
#include "estimator/drift_model.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace esg::estimator {
namespace {

// The coefficient of `c` a descriptor names, by its symbol and component (drift_model.h).
double ByName(const DriftCoefficients& c, const FixedTermDescriptor& term) {
  if (term.symbol == "k0") return c.k0;
  if (term.symbol == "C1") return c.C1[term.component];
  if (term.symbol == "C2") return c.C2[term.component];
  if (term.symbol == "mu") return c.mu[term.component];
  if (term.symbol == "nu") return c.nu[term.component];
  ADD_FAILURE() << "unknown symbol " << term.symbol;
  return 0.0;
}

TEST(ModelTerms, ThetaIndexIsTheCoefficientTheSymbolAndComponentName) {
  for (const FixedTermDescriptor& term : kFixedTerms) {
    DriftVector theta = DriftVector::Zero();
    theta[term.theta_index] = 1.0;
    const DriftCoefficients c = DriftCoefficients::FromVector(theta);
    EXPECT_EQ(ByName(c, term), 1.0) << term.label;
    EXPECT_EQ(c.AsVector().sum(), 1.0) << term.label;
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

// "c1DegH" -> "c1_deg_h": the proto field name of a JSON key (the proto3 JSON mapping).
std::string ProtoFieldName(absl::string_view json_key) {
  std::string out;
  for (char c : json_key) {
    if (absl::ascii_isupper(static_cast<unsigned char>(c))) {
      out += '_';
      out += absl::ascii_tolower(static_cast<unsigned char>(c));
    } else {
      out += c;
    }
  }
  return out;
}

// The console cannot include C++: its table of coefficients (COEFFICIENTS: telemetry key, label,
// the GyroDriftModel field it reads) is checked against the descriptors, row for row.
TEST(ModelTerms, ConsoleLabelsAreTheDescriptorsInOrder) {
  std::ifstream in(std::string(ESG_SOURCE_DIR) + "/console/plugin/series.js");
  ASSERT_TRUE(in.good());
  std::stringstream text;
  text << in.rdbuf();
  const std::string js = text.str();
  const size_t begin = js.find("export const COEFFICIENTS = [");
  ASSERT_NE(begin, std::string::npos);
  const size_t end = js.find("].map(", begin);
  ASSERT_NE(end, std::string::npos);
  const std::string table = js.substr(begin, end - begin);
  // ['c11', 'C11', (m) => m.c1_deg_h[0]],
  const std::regex row(R"(\['([^']*)', '([^']*)', \(m\) => m\.([a-z0-9_]+)(\[(\d)\])?\])");
  std::vector<std::string> rows;
  for (std::sregex_iterator it(table.begin(), table.end(), row), done; it != done; ++it) {
    const std::smatch& m = *it;
    rows.push_back(absl::StrCat(m[1].str(), " ", m[2].str(), " ", m[3].str(), " ",
                                m[5].matched ? m[5].str() : "-1"));
  }
  std::vector<std::string> expected;
  for (const FixedTermDescriptor& term : kFixedTerms) {
    expected.push_back(absl::StrCat(absl::AsciiStrToLower(term.label), " ", term.label, " ",
                                    ProtoFieldName(term.json_key), " ", term.component));
  }
  EXPECT_THAT(rows, ::testing::ElementsAreArray(expected));
}

// Where a fixed term is named: the production files (not tests, docs or fuzz corpora) that name
// the last term of theta, nu (eq. (1)), by any of its names: JSON key, proto field, component
// labels, theta offset, DriftCoefficients member or the model flag. A new fixed term is written
// where nu is. Pinned, so a new place that names the terms one by one fails here instead of
// growing unseen, and a place converted to the table must leave the list.
TEST(ModelTerms, TheFilesThatNameAFixedTermAreTheKnownOnes) {
  // A new term is necessarily written in these: its descriptor, its physics (regressor and
  // coefficient struct), its wire field, the model strings that include it, the console's labels
  // (checked against the table above).
  const std::set<std::string> per_term = {
      "estimator/model_terms.h",       "estimator/drift_model.h",
      "estimator/drift_model.cc",      "proto/esg/v1/spacecraft_config.proto",
      "estimator/calibration_model.h", "estimator/calibration_model.cc",
      "console/plugin/series.js"};
  // Not yet reading the table (issue 34 item 1): the simulator's independent truth model, the
  // diagnosis' candidates and report, the CLI's calibrate/simulate/scenario and the console's
  // diagnosis labels; frozen schema history and the storage layout offsets.
  const std::set<std::string> not_yet = {
      "estimator/simulator_truth.h",          "estimator/simulator_truth.cc",
      "estimator/session.cc",                 "estimator/discovery/candidates.h",
      "estimator/discovery/candidates.cc",    "estimator/discovery/diagnose.cc",
      "estimator/discovery/options.h",        "estimator/discovery/report.cc",
      "client/commands/calibrate.cc",         "client/commands/simulate.cc",
      "client/scenario.cc",                   "console/plugin/diagnosisView.js",
      "storage/records.h",                    "storage/schema.cc",
      "storage/postgres_schema.cc"};
  const std::regex names(R"(nuDegH|nu_deg_h|nu23|nu31|nu12|kThetaNu|kCoefficientNu|\.nu\b|mu_nu)");
  const std::filesystem::path root(ESG_SOURCE_DIR);
  std::set<std::string> found;
  for (const char* dir : {"estimator", "proto", "storage", "server", "client", "console/plugin",
                          "console/gateway"}) {
    for (const auto& entry : std::filesystem::recursive_directory_iterator(root / dir)) {
      const std::string ext = entry.path().extension().string();
      if (!entry.is_regular_file() ||
          (ext != ".h" && ext != ".cc" && ext != ".proto" && ext != ".js")) {
        continue;
      }
      std::ifstream in(entry.path());
      std::stringstream text;
      text << in.rdbuf();
      const std::string content = text.str();
      if (std::regex_search(content, names)) {
        found.insert(std::filesystem::relative(entry.path(), root).generic_string());
      }
    }
  }
  std::set<std::string> expected = per_term;
  expected.insert(not_yet.begin(), not_yet.end());
  EXPECT_THAT(found, ::testing::ContainerEq(expected));
  EXPECT_EQ(per_term.size(), 7u);
}

}  // namespace
}  // namespace esg::estimator
