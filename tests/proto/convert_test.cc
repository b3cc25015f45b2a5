// Tests of proto/convert: the configuration JSON (docs/formats.md) and its SI values, JSON and file
// round trips, configuration errors naming the JSON field, telemetry frame conversion and
// validation, timestamp helpers.
#include "proto/convert.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <numbers>
#include <random>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_replace.h"
#include "absl/time/time.h"
#include "estimator/model_terms.h"
#include "gmock/gmock.h"
#include "google/protobuf/util/json_util.h"
#include "gtest/gtest.h"
#include "tests/testing/status_matchers.h"
#include "tests/testing/temp_dir.h"

namespace esg::proto_convert {
namespace {

using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::HasSubstr;
using ::testing::Not;

// The term's deprecated field (found by the descriptor's JSON key, so this names no field), or
// null for a term added to the table after the release before (it is keyed only).
const google::protobuf::FieldDescriptor* FieldOf(const estimator::FixedTermDescriptor& term) {
  return esg::v1::GyroDriftModel::descriptor()->FindFieldByCamelcaseName(
      std::string(term.json_key));
}

// The release before's form of a drift model: the coefficient in its deprecated field, the
// vector's other entries 0 until set.
void SetByField(const estimator::FixedTermDescriptor& term, double deg_h,
                esg::v1::GyroDriftModel* model) {
  const google::protobuf::FieldDescriptor* f = FieldOf(term);
  ASSERT_NE(f, nullptr) << term.json_key;
  const google::protobuf::Reflection* reflection = model->GetReflection();
  if (!f->is_repeated()) {
    reflection->SetDouble(model, f, deg_h);
    return;
  }
  while (reflection->FieldSize(*model, f) <= term.component) reflection->AddDouble(model, f, 0.0);
  reflection->SetRepeatedDouble(model, f, term.component, deg_h);
}

// Whether the term's deprecated field holds anything.
bool GivenByAField(const esg::v1::GyroDriftModel& model, const estimator::FixedTermDescriptor& term) {
  const google::protobuf::FieldDescriptor* f = FieldOf(term);
  if (f == nullptr) return false;
  const google::protobuf::Reflection* reflection = model.GetReflection();
  return f->is_repeated() ? reflection->FieldSize(model, f) > 0 : reflection->HasField(model, f);
}

// Independent of units.h on purpose: the expected values are computed from first principles.
constexpr double kPi = std::numbers::pi;
double DegHToRadS(double x) { return x * kPi / 180.0 / 3600.0; }
double ArcsecToRadians(double x) { return x / 3600.0 * kPi / 180.0; }

// A configuration in the form of docs/formats.md with three gyros (gyro 2 mounted turned 90 deg
// about body z so that row-major order is visible, gyro 3 about body x).
constexpr char kDesignJson[] = R"json({
  "spacecraftId": "RDK-1",
  "gyros": [
    {"id": 1, "caseToBody": [1,0,0, 0,1,0, 0,0,1],
     "model":      {"k0DegH": 0.12, "c1DegH": [0,0,0], "c2DegH": [0,0,0],
                    "muDegH": [0,0,0], "nuDegH": [0,0,0]},
     "modelSigma": {"k0DegH": 0.3,  "c1DegH": [0.1,0.1,0.1], "c2DegH": [0.1,0.1,0.1]}},
    {"id": 2, "caseToBody": [0,-1,0, 1,0,0, 0,0,1],
     "model":      {"k0DegH": -0.2, "c1DegH": [0.05,-0.02,0.01], "c2DegH": [0,0,0.03],
                    "muDegH": [0,0,0], "nuDegH": [0,0,0]},
     "modelSigma": {"k0DegH": 0.3,  "c1DegH": [0.1,0.1,0.1], "c2DegH": [0.1,0.1,0.1]}},
    {"id": 3, "caseToBody": [1,0,0, 0,0,-1, 0,1,0],
     "model":      {"k0DegH": 0.25},
     "modelSigma": {"k0DegH": 0.3,  "c1DegH": [0.1,0.1,0.1], "c2DegH": [0.1,0.1,0.1]}}
  ],
  "workingPair": [1, 2],
  "reservePair": [1, 3],
  "starTracker": {"noiseArcsec": [5, 5, 30]},
  "readoutNoiseArcsec": 3,
  "randomWalkDegHSqrtH": 0.002
})json";

// Gyro 3's model and modelSigma as kDesignJson writes them (the one place they are so).
constexpr char kGyro3Sigma[] =
    "{\"k0DegH\": 0.25},\n     \"modelSigma\": {\"k0DegH\": 0.3,  \"c1DegH\": [0.1,0.1,0.1], "
    "\"c2DegH\": [0.1,0.1,0.1]}}";

std::string DesignJsonWith(absl::string_view from, absl::string_view to) {
  std::string json = kDesignJson;
  const std::string replaced = absl::StrReplaceAll(json, {{from, to}});
  EXPECT_NE(replaced, json) << "test bug: '" << from << "' not found in the example";
  return replaced;
}

TEST(ConfigJson, DesignExampleParsesToSiValues) {
  absl::StatusOr<estimator::SpacecraftConfig> parsed = ParseConfigJson(kDesignJson);
  ASSERT_THAT(parsed, IsOk());
  const estimator::SpacecraftConfig& c = *parsed;
  EXPECT_EQ(c.spacecraft_id, "RDK-1");
  ASSERT_EQ(c.gyros.size(), 3u);
  EXPECT_EQ(c.gyros[0].id, 1);
  EXPECT_EQ(c.gyros[2].id, 3);
  // k0 0.12 deg/h -> rad/s (about 5.8e-7).
  EXPECT_DOUBLE_EQ(c.gyros[0].model.k0, DegHToRadS(0.12));
  EXPECT_NEAR(c.gyros[0].model.k0, 5.8178e-7, 1e-10);
  EXPECT_DOUBLE_EQ(c.gyros[0].model_sigma.k0, DegHToRadS(0.3));
  EXPECT_DOUBLE_EQ(c.gyros[0].model_sigma.C1.y(), DegHToRadS(0.1));
  EXPECT_DOUBLE_EQ(c.gyros[0].model_sigma.C2.z(), DegHToRadS(0.1));
  EXPECT_TRUE(c.gyros[0].model_sigma.mu.isZero(0.0));  // absent in the example -> 0
  EXPECT_DOUBLE_EQ(c.gyros[1].model.k0, DegHToRadS(-0.2));
  EXPECT_DOUBLE_EQ(c.gyros[1].model.C1.x(), DegHToRadS(0.05));
  EXPECT_DOUBLE_EQ(c.gyros[1].model.C1.y(), DegHToRadS(-0.02));
  EXPECT_DOUBLE_EQ(c.gyros[1].model.C2.z(), DegHToRadS(0.03));
  EXPECT_TRUE(c.gyros[2].model.C1.isZero(0.0));  // empty vectors are zero
  // caseToBody is C_b_k row-major: gyro 2's case x axis is body y.
  EXPECT_EQ(c.gyros[1].C_b_k(0, 1), -1.0);
  EXPECT_EQ(c.gyros[1].C_b_k(1, 0), 1.0);
  EXPECT_TRUE((c.gyros[1].C_b_k * Eigen::Vector3d::UnitX()).isApprox(Eigen::Vector3d::UnitY()));
  EXPECT_TRUE((c.gyros[2].C_b_k * Eigen::Vector3d::UnitY()).isApprox(Eigen::Vector3d::UnitZ()));
  EXPECT_EQ(c.working_pair, (std::array<int, 2>{1, 2}));
  EXPECT_EQ(c.reserve_pair, (std::array<int, 2>{1, 3}));
  // Arcsec -> rad.
  EXPECT_DOUBLE_EQ(c.star_tracker.noise.x(), ArcsecToRadians(5));
  EXPECT_DOUBLE_EQ(c.star_tracker.noise.z(), ArcsecToRadians(30));
  EXPECT_NEAR(c.star_tracker.noise.z(), 1.4544e-4, 1e-8);
  EXPECT_DOUBLE_EQ(c.readout_noise, ArcsecToRadians(3));
  // deg/h/sqrt(h) -> rad/s/sqrt(s): (0.002 deg/h) / sqrt(3600 s).
  EXPECT_DOUBLE_EQ(c.random_walk, DegHToRadS(0.002) / std::sqrt(3600.0));
  // Absent suspension and filter take the documented defaults.
  EXPECT_DOUBLE_EQ(c.suspension.amplifier_gain, 200.0);
  EXPECT_DOUBLE_EQ(c.suspension.reference_voltage, 200.0);
  EXPECT_DOUBLE_EQ(c.suspension.gap, 30e-6);
  EXPECT_DOUBLE_EQ(c.filter.integration_rate_hz, 8.0);
  EXPECT_DOUBLE_EQ(c.filter.measurement_step, 60.0);
  EXPECT_DOUBLE_EQ(c.filter.innovation_kd, 5.0);
  EXPECT_EQ(c.filter.fault_threshold, 0.0);
  EXPECT_EQ(c.gyros[0].misalignment_sigma, 0.0);
}

TEST(ConfigJson, ExtraFieldsBeyondDesignAreRead) {
  const std::string json = DesignJsonWith(
      R"("randomWalkDegHSqrtH": 0.002)",
      R"("randomWalkDegHSqrtH": 0.002,
         "suspension": {"amplifierGain": 150, "referenceVoltageV": 180, "gapUm": 25},
         "filter": {"integrationRateHz": 4, "measurementStepS": 30, "innovationKd": 4.5,
                    "faultThresholdArcsec": 60})");
  const std::string with_misalignment =
      absl::StrReplaceAll(json, {{R"("id": 2,)", R"("id": 2, "misalignmentSigmaArcsec": 20,)"}});
  absl::StatusOr<estimator::SpacecraftConfig> c = ParseConfigJson(with_misalignment);
  ASSERT_THAT(c, IsOk());
  EXPECT_DOUBLE_EQ(c->suspension.amplifier_gain, 150.0);
  EXPECT_DOUBLE_EQ(c->suspension.reference_voltage, 180.0);
  EXPECT_DOUBLE_EQ(c->suspension.gap, 25e-6);
  EXPECT_DOUBLE_EQ(c->filter.integration_rate_hz, 4.0);
  EXPECT_DOUBLE_EQ(c->filter.measurement_step, 30.0);
  EXPECT_DOUBLE_EQ(c->filter.innovation_kd, 4.5);
  EXPECT_DOUBLE_EQ(c->filter.fault_threshold, ArcsecToRadians(60));
  EXPECT_DOUBLE_EQ(c->gyros[1].misalignment_sigma, ArcsecToRadians(20));
  EXPECT_EQ(c->gyros[0].misalignment_sigma, 0.0);
}

// A configuration with every field away from its default and irrational-looking values.
estimator::SpacecraftConfig RichConfig() {
  estimator::SpacecraftConfig c;
  c.spacecraft_id = "SAT-7.Zvezda:b_1";  // every punctuation the identifier rule allows
  std::mt19937_64 rng(20190301);
  std::normal_distribution<double> normal(0.0, 1.0);
  for (int id : {1, 2, 4}) {
    estimator::GyroConfig g;
    g.id = id;
    Eigen::Quaterniond q(normal(rng), normal(rng), normal(rng), normal(rng));
    g.C_b_k = q.normalized().toRotationMatrix();
    g.model.k0 = 3e-6 * normal(rng);
    g.model.C1 = 1e-6 * Eigen::Vector3d(normal(rng), normal(rng), normal(rng));
    g.model.C2 = 1e-6 * Eigen::Vector3d(normal(rng), normal(rng), normal(rng));
    g.model.mu = 1e-7 * Eigen::Vector3d(normal(rng), normal(rng), normal(rng));
    g.model.nu = 1e-7 * Eigen::Vector3d(normal(rng), normal(rng), normal(rng));
    g.model_sigma.k0 = 1.4e-6;
    g.model_sigma.C1 = Eigen::Vector3d(4.8e-7, 4.9e-7, 5.0e-7);
    g.model_sigma.nu = Eigen::Vector3d(1e-8, 0.0, 3e-8);
    g.misalignment_sigma = 1e-4 * id;
    c.gyros.push_back(g);
  }
  // Basis terms of every kind on gyro 1 (held and free), a readout distortion on gyro 2.
  using estimator::BasisKind;
  using estimator::BasisTerm;
  auto term = [&](BasisKind kind, int axis) {
    BasisTerm t;
    t.kind = kind;
    t.axis = axis;
    t.value = 1e-7 * normal(rng);
    return t;
  };
  BasisTerm harmonic = term(BasisKind::kSpinAxisHarmonic, 3);
  harmonic.exponents = {1, 0, 2};
  harmonic.sigma = 4.1e-7;
  BasisTerm rate = term(BasisKind::kBodyRate, 1);
  rate.index = {2, 1};
  rate.value = 3e-4 * normal(rng);  // per rad/s
  BasisTerm product = term(BasisKind::kBodyRateProduct, 2);
  product.index = {2, 3};
  product.value = 1e-3 * normal(rng);
  BasisTerm orbit = term(BasisKind::kOrbitalHarmonic, 2);
  orbit.harmonic = 3;
  orbit.sine = true;
  orbit.period = 5561.25;
  orbit.epoch = absl::FromUnixSeconds(1551398400) + absl::Nanoseconds(123456789);
  orbit.sigma = 2.2e-7;
  BasisTerm ramp = term(BasisKind::kRamp, 1);
  ramp.value = 1e-12 * normal(rng);  // per s
  ramp.epoch = absl::FromUnixSeconds(1551398400);
  BasisTerm ramp_h = term(BasisKind::kRampHarmonic, 3);
  ramp_h.index = {3, 1};
  ramp_h.value = 1e-12 * normal(rng);
  BasisTerm voltage = term(BasisKind::kSuspensionVoltage, 2);
  voltage.index = {1, 1};
  voltage.sigma = 1e-7;
  BasisTerm decay = term(BasisKind::kExponentialDecay, 1);
  decay.time_constant = 14760.5;
  decay.epoch = absl::FromUnixSeconds(1551398400);
  decay.sigma = 3e-7;
  c.gyros[0].basis_terms = {harmonic, rate, product, orbit, ramp, ramp_h, voltage, decay};
  Eigen::Matrix3d D;
  D << 1e-3, -2e-4, 3e-5, -2e-4, -5e-4, 7e-4, 3e-5, 7e-4, 2.5e-3;
  c.gyros[1].readout_distortion = D;
  c.working_pair = {4, 1};
  c.reserve_pair = {2, 4};
  c.star_tracker.noise = Eigen::Vector3d(2.1e-5, 2.2e-5, 1.3e-4);
  c.readout_noise = 1.7e-5;
  c.random_walk = 1.23e-10;
  c.suspension = {190.0, 210.0, 28.5e-6};
  c.filter = {10.0, 30.0, 4.0, 2.9e-4};
  return c;
}

void ExpectNear(double a, double b, const std::string& what) {
  EXPECT_NEAR(a, b, 1e-14 * std::max(std::abs(a), std::abs(b))) << what;
}

void ExpectConfigsEqual(const estimator::SpacecraftConfig& a, const estimator::SpacecraftConfig& b) {
  EXPECT_EQ(a.spacecraft_id, b.spacecraft_id);
  ASSERT_EQ(a.gyros.size(), b.gyros.size());
  for (size_t i = 0; i < a.gyros.size(); ++i) {
    const std::string at = "gyro index " + std::to_string(i);
    EXPECT_EQ(a.gyros[i].id, b.gyros[i].id);
    EXPECT_EQ(a.gyros[i].C_b_k, b.gyros[i].C_b_k) << at;  // no unit conversion: exact
    for (int k = 0; k < estimator::kNumDriftCoefficients; ++k) {
      ExpectNear(a.gyros[i].model.AsVector()[k], b.gyros[i].model.AsVector()[k], at + " model");
      ExpectNear(a.gyros[i].model_sigma.AsVector()[k], b.gyros[i].model_sigma.AsVector()[k],
                 at + " sigma");
    }
    ExpectNear(a.gyros[i].misalignment_sigma, b.gyros[i].misalignment_sigma, at);
    EXPECT_EQ(a.gyros[i].readout_distortion, b.gyros[i].readout_distortion) << at;  // exact
    ASSERT_EQ(a.gyros[i].basis_terms.size(), b.gyros[i].basis_terms.size()) << at;
    for (size_t k = 0; k < a.gyros[i].basis_terms.size(); ++k) {
      const estimator::BasisTerm& x = a.gyros[i].basis_terms[k];
      const estimator::BasisTerm& y = b.gyros[i].basis_terms[k];
      const std::string term = at + " basis term " + std::to_string(k);
      EXPECT_EQ(x.kind, y.kind) << term;
      EXPECT_EQ(x.axis, y.axis) << term;
      EXPECT_EQ(x.exponents, y.exponents) << term;
      EXPECT_EQ(x.index[0], y.index[0]) << term;
      if (x.kind == estimator::BasisKind::kBodyRateProduct) EXPECT_EQ(x.index[1], y.index[1]) << term;
      EXPECT_EQ(x.harmonic, y.harmonic) << term;
      EXPECT_EQ(x.sine, y.sine) << term;
      EXPECT_EQ(x.period, y.period) << term;
      EXPECT_EQ(x.time_constant, y.time_constant) << term;
      EXPECT_EQ(x.epoch, y.epoch) << term;
      ExpectNear(x.value, y.value, term + " value");
      ExpectNear(x.sigma, y.sigma, term + " sigma");
    }
  }
  EXPECT_EQ(a.working_pair, b.working_pair);
  EXPECT_EQ(a.reserve_pair, b.reserve_pair);
  for (int k = 0; k < 3; ++k) {
    ExpectNear(a.star_tracker.noise[k], b.star_tracker.noise[k], "noise");
  }
  ExpectNear(a.readout_noise, b.readout_noise, "readout_noise");
  ExpectNear(a.random_walk, b.random_walk, "random_walk");
  EXPECT_EQ(a.suspension.amplifier_gain, b.suspension.amplifier_gain);
  EXPECT_EQ(a.suspension.reference_voltage, b.suspension.reference_voltage);
  ExpectNear(a.suspension.gap, b.suspension.gap, "gap");
  EXPECT_EQ(a.filter.integration_rate_hz, b.filter.integration_rate_hz);
  EXPECT_EQ(a.filter.measurement_step, b.filter.measurement_step);
  EXPECT_EQ(a.filter.innovation_kd, b.filter.innovation_kd);
  ExpectNear(a.filter.fault_threshold, b.filter.fault_threshold, "fault_threshold");
}

// Found by fuzz/fuzz_config_json.cc (docs/fuzzing.md, finding 5): a drift coefficient of -0.0
// was written as -0, which protobuf's JSON parser reads as 0, so the written JSON did not read
// back to itself. The fuzzer's input changed one value of rdk1.json to -0.0; here the same.
TEST(ConfigJson, NegativeZeroIsWrittenAsZeroAndTheWrittenJsonIsAFixedPoint) {
  const std::string json = R"({"spacecraftId": "RDK-1",
    "gyros": [{"id": 1, "caseToBody": [1, 0, 0, 0, 1, 0, 0, 0, 1],
               "model": {"k0DegH": 0.25, "c2DegH": [0.015, 0, -0.0]},
               "modelSigma": {"k0DegH": 0.3}},
              {"id": 2, "caseToBody": [0, 0, 1, 0, 1, 0, -1, 0, 0], "modelSigma": {"k0DegH": 0.3}}],
    "workingPair": [1, 2], "reservePair": [1, 2], "starTracker": {"noiseArcsec": [5, 5, 30]}})";
  absl::StatusOr<estimator::SpacecraftConfig> config = ParseConfigJson(json);
  ASSERT_TRUE(config.ok()) << config.status();
  const std::string written = ConfigToJson(*config);
  EXPECT_THAT(written, Not(HasSubstr("-0,")));
  EXPECT_THAT(written, Not(HasSubstr("-0]")));
  EXPECT_THAT(written, Not(HasSubstr("-0}")));  // a keyed coefficient
  absl::StatusOr<estimator::SpacecraftConfig> back = ParseConfigJson(written);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(ConfigToJson(*back), written);
}

TEST(ConfigJson, RoundTripConfigJsonConfigIsEqual) {
  const estimator::SpacecraftConfig original = RichConfig();
  ASSERT_THAT(estimator::ValidateConfig(original), IsOk());
  const std::string json = ConfigToJson(original);
  EXPECT_THAT(json, HasSubstr("{\"term\": \"k0\", \"valueDegH\": "));
  EXPECT_THAT(json, HasSubstr("\"caseToBody\""));
  EXPECT_THAT(json, HasSubstr("\"randomWalkDegHSqrtH\""));
  absl::StatusOr<estimator::SpacecraftConfig> parsed = ParseConfigJson(json);
  ASSERT_THAT(parsed, IsOk()) << json;
  ExpectConfigsEqual(original, *parsed);
  // A second trip through JSON is textually stable.
  EXPECT_EQ(ConfigToJson(*parsed), json);
}

// The JSON form of basis terms (deg/h per JSON unit of s, kind by name, epoch in RFC 3339) and of
// the readout distortion: read to SI, written back to the same JSON.
TEST(ConfigJson, BasisTermsAndReadoutDistortionRoundTripInJsonUnits) {
  const std::string json = DesignJsonWith(
      "\"modelSigma\": {\"k0DegH\": 0.3,  \"c1DegH\": [0.1,0.1,0.1], \"c2DegH\": [0.1,0.1,0.1]}},\n"
      "    {\"id\": 2,",
      "\"modelSigma\": {\"k0DegH\": 0.3,  \"c1DegH\": [0.1,0.1,0.1], \"c2DegH\": [0.1,0.1,0.1]},\n"
      "     \"basisTerms\": [\n"
      "       {\"kind\": \"spin_axis_harmonic\", \"axis\": 2, \"exponents\": [0, 0, 0],"
      " \"valueDegH\": 0.02, \"sigmaDegH\": 0.1},\n"
      "       {\"kind\": \"body_rate\", \"axis\": 3, \"index\": [1], \"valueDegH\": 0.002},\n"
      "       {\"kind\": \"ramp\", \"axis\": 1, \"epoch\": \"2019-03-01T06:00:00Z\","
      " \"valueDegH\": 0.001},\n"
      "       {\"kind\": \"orbital_harmonic\", \"axis\": 1, \"harmonic\": 2, \"sine\": true,"
      " \"periodS\": 5400, \"valueDegH\": -0.01}],\n"
      "     \"readoutDistortion\": [0.001, 0.0002, 0, 0.0002, -0.001, 0, 0, 0, 0]},\n"
      "    {\"id\": 2,");
  absl::StatusOr<estimator::SpacecraftConfig> c = ParseConfigJson(json);
  ASSERT_THAT(c, IsOk());
  const estimator::GyroConfig& g = c->gyros[0];
  ASSERT_EQ(g.basis_terms.size(), 4u);
  const estimator::BasisTerm& fixed = g.basis_terms[0];
  EXPECT_EQ(fixed.kind, estimator::BasisKind::kSpinAxisHarmonic);
  EXPECT_EQ(fixed.axis, 2);
  EXPECT_NEAR(fixed.value, DegHToRadS(0.02), 1e-20);
  EXPECT_NEAR(fixed.sigma, DegHToRadS(0.1), 1e-20);
  // 0.002 deg/h per deg/s = 0.002 / 3600 * 180 / pi rad/s per deg/s, and deg/s = rad/s * 180 / pi.
  const estimator::BasisTerm& rate = g.basis_terms[1];
  EXPECT_EQ(rate.kind, estimator::BasisKind::kBodyRate);
  EXPECT_EQ(rate.index[0], 1);
  EXPECT_NEAR(rate.value, DegHToRadS(0.002) * 180.0 / kPi, 1e-18);
  EXPECT_EQ(rate.sigma, 0.0);
  // 0.001 deg/h per hour of ramp, s in seconds: / 3600.
  const estimator::BasisTerm& ramp = g.basis_terms[2];
  EXPECT_NEAR(ramp.value, DegHToRadS(0.001) / 3600.0, 1e-22);
  EXPECT_EQ(ramp.epoch, absl::FromUnixSeconds(1551398400 + 6 * 3600));
  const estimator::BasisTerm& orbit = g.basis_terms[3];
  EXPECT_EQ(orbit.harmonic, 2);
  EXPECT_TRUE(orbit.sine);
  EXPECT_EQ(orbit.period, 5400.0);
  EXPECT_EQ(g.readout_distortion(0, 1), 0.0002);
  EXPECT_EQ(g.readout_distortion(1, 1), -0.001);
  EXPECT_TRUE(c->gyros[1].basis_terms.empty());
  EXPECT_TRUE(c->gyros[1].readout_distortion.isZero(0.0));
  const std::string written = ConfigToJson(*c);
  EXPECT_THAT(written, HasSubstr("\"kind\": \"body_rate\""));
  EXPECT_THAT(written, HasSubstr("\"valueDegH\": 0.002,"));
  EXPECT_THAT(written, HasSubstr("\"index\": [1]"));
  EXPECT_THAT(written, HasSubstr("\"epoch\": \"2019-03-01T06:00:00Z\""));
  EXPECT_THAT(written, HasSubstr("\"readoutDistortion\": [0.001, 0.0002, 0, 0.0002, -0.001, 0, 0, 0, 0]"));
  absl::StatusOr<estimator::SpacecraftConfig> back = ParseConfigJson(written);
  ASSERT_THAT(back, IsOk()) << written;
  ExpectConfigsEqual(*c, *back);
  EXPECT_EQ(ConfigToJson(*back), written);
  // Only an exponential decay carries its time constant (docs/formats.md "BasisTerm"): the JSON
  // of the other kinds is as before.
  EXPECT_THAT(written, Not(HasSubstr("timeConstantS")));
}

// An exponential decay (a warm-up from an onset, docs/formats.md "BasisTerm"): its time constant
// in seconds, its onset the epoch, its coefficient in deg/h (s has unit 1); written back to the
// same JSON.
TEST(ConfigJson, ExponentialDecayRoundTripsWithItsTimeConstant) {
  const std::string json = DesignJsonWith(
      "\"modelSigma\": {\"k0DegH\": 0.3,  \"c1DegH\": [0.1,0.1,0.1], \"c2DegH\": [0.1,0.1,0.1]}},\n"
      "    {\"id\": 2,",
      "\"modelSigma\": {\"k0DegH\": 0.3,  \"c1DegH\": [0.1,0.1,0.1], \"c2DegH\": [0.1,0.1,0.1]},\n"
      "     \"basisTerms\": [\n"
      "       {\"kind\": \"exponential_decay\", \"axis\": 2, \"timeConstantS\": 14400,"
      " \"epoch\": \"2019-03-01T06:00:00Z\", \"valueDegH\": 0.1, \"sigmaDegH\": 0.2}]},\n"
      "    {\"id\": 2,");
  absl::StatusOr<estimator::SpacecraftConfig> c = ParseConfigJson(json);
  ASSERT_THAT(c, IsOk());
  ASSERT_EQ(c->gyros[0].basis_terms.size(), 1u);
  const estimator::BasisTerm& t = c->gyros[0].basis_terms[0];
  EXPECT_EQ(t.kind, estimator::BasisKind::kExponentialDecay);
  EXPECT_EQ(t.axis, 2);
  EXPECT_EQ(t.time_constant, 14400.0);
  EXPECT_EQ(t.epoch, absl::FromUnixSeconds(1551398400 + 6 * 3600));
  EXPECT_NEAR(t.value, DegHToRadS(0.1), 1e-20);
  EXPECT_NEAR(t.sigma, DegHToRadS(0.2), 1e-20);
  const std::string written = ConfigToJson(*c);
  EXPECT_THAT(written, HasSubstr("\"kind\": \"exponential_decay\""));
  EXPECT_THAT(written, HasSubstr("\"timeConstantS\": 14400"));
  absl::StatusOr<estimator::SpacecraftConfig> back = ParseConfigJson(written);
  ASSERT_THAT(back, IsOk()) << written;
  ExpectConfigsEqual(*c, *back);
  EXPECT_EQ(ConfigToJson(*back), written);
}

TEST(ConfigJson, WrittenConfigIsCompleteEvenForZeros) {
  absl::StatusOr<estimator::SpacecraftConfig> c = ParseConfigJson(kDesignJson);
  ASSERT_THAT(c, IsOk());
  const std::string json = ConfigToJson(*c);
  // Zero-valued fields are printed, with the defaults that were applied.
  EXPECT_THAT(json, HasSubstr("\"misalignmentSigmaArcsec\": 0"));
  EXPECT_THAT(json, HasSubstr("\"faultThresholdArcsec\": 0"));
  EXPECT_THAT(json, HasSubstr("\"amplifierGain\": 200"));
  EXPECT_THAT(json, HasSubstr("\"gapUm\": 30\n"));
  // Every drift coefficient keyed, zeros too, one to a line; no deprecated field.
  EXPECT_THAT(json, HasSubstr("\n          {\"term\": \"k0\", \"valueDegH\": 0.12},\n"));
  EXPECT_THAT(json, HasSubstr("{\"term\": \"mu23\", \"valueDegH\": 0}"));
  EXPECT_THAT(json, Not(HasSubstr("DegH\": [")));
  EXPECT_THAT(json, Not(HasSubstr("k0DegH")));
  EXPECT_THAT(json, HasSubstr("\"caseToBody\": [1, 0, 0, 0, 1, 0, 0, 0, 1]"));
}

TEST(ConfigFile, WriteThenReadGivesTheSameConfig) {
  esg::testing::TempDir dir;
  const std::string path = dir.File("sat7.json");
  const estimator::SpacecraftConfig original = RichConfig();
  ASSERT_THAT(WriteConfigFile(path, original), IsOk());
  absl::StatusOr<estimator::SpacecraftConfig> read = ReadConfigFile(path);
  ASSERT_THAT(read, IsOk());
  ExpectConfigsEqual(original, *read);
}

TEST(ConfigFile, MissingFileIsNotFound) {
  esg::testing::TempDir dir;
  EXPECT_THAT(ReadConfigFile(dir.File("absent.json")),
              StatusIs(absl::StatusCode::kNotFound, HasSubstr("absent.json")));
}

TEST(ConfigFile, BadContentNamesFileAndField) {
  esg::testing::TempDir dir;
  const std::string path = dir.File("bad.json");
  std::ofstream(path) << DesignJsonWith("\"readoutNoiseArcsec\": 3", "\"readoutNoiseArcsec\": -3");
  EXPECT_THAT(ReadConfigFile(path),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       ::testing::AllOf(HasSubstr("bad.json"), HasSubstr("readoutNoiseArcsec"))));
}

TEST(ConfigFile, InvalidConfigIsNotWritten) {
  esg::testing::TempDir dir;
  const std::string path = dir.File("never.json");
  estimator::SpacecraftConfig c = RichConfig();
  c.working_pair = {1, 3};  // gyro 3 is not configured
  EXPECT_THAT(WriteConfigFile(path, c),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("workingPair")));
  EXPECT_FALSE(std::ifstream(path).good());
}

struct BadConfigCase {
  std::string name;
  std::string from;
  std::string to;
  std::string expected_message;
};

void PrintTo(const BadConfigCase& c, std::ostream* os) { *os << c.name; }

class BadConfig : public ::testing::TestWithParam<BadConfigCase> {};

TEST_P(BadConfig, IsInvalidArgumentNamingTheField) {
  const BadConfigCase& c = GetParam();
  EXPECT_THAT(ParseConfigJson(DesignJsonWith(c.from, c.to)),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr(c.expected_message)));
}

INSTANTIATE_TEST_SUITE_P(
    ConfigJson, BadConfig,
    ::testing::Values(
        BadConfigCase{"NonRotationCaseToBody", "[0,-1,0, 1,0,0, 0,0,1]", "[0,-1,0, 1,0,0, 0,0,2]",
                      "gyros[1].caseToBody: not a proper rotation"},
        BadConfigCase{"ReflectionCaseToBody", "[0,-1,0, 1,0,0, 0,0,1]", "[0,-1,0, 1,0,0, 0,0,-1]",
                      "gyros[1].caseToBody: not a proper rotation"},
        BadConfigCase{"CaseToBodyWrongLength", "[1,0,0, 0,0,-1, 0,1,0]", "[1,0,0, 0,0,-1, 0,1]",
                      "gyros[2].caseToBody: expected 9 values (C_b_k row-major), got 8"},
        BadConfigCase{"VectorWrongLength", "\"c1DegH\": [0.05,-0.02,0.01]",
                      "\"c1DegH\": [0.05,-0.02]",
                      "gyros[1].model.c1DegH: expected 3 values, got 2"},
        BadConfigCase{"NoiseWrongLength", "[5, 5, 30]", "[5, 5, 30, 1]",
                      "starTracker.noiseArcsec: expected 3 values, got 4"},
        BadConfigCase{"UnknownField", "\"id\": 1,", "\"id\": 1, \"k0\": 0.1,",
                      "gyros[0].k0: unknown field"},
        BadConfigCase{"UnknownTopLevelField", "\"readoutNoiseArcsec\": 3",
                      "\"readoutNoiseArcsec\": 3, \"readoutNoise\": 3",
                      "readoutNoise: unknown field"},
        BadConfigCase{"DuplicateGyroId", "\"id\": 3,", "\"id\": 2,",
                      "gyros[2].id: gyro 2 is configured twice"},
        BadConfigCase{"GyroIdOutOfRange", "\"id\": 3,", "\"id\": 5,",
                      "gyros[2].id: 5 is outside 1..4"},
        BadConfigCase{"PairNamesMissingGyro", "\"reservePair\": [1, 3]", "\"reservePair\": [1, 4]",
                      "reservePair: gyro 4 is not among the configured gyros"},
        BadConfigCase{"PairWrongLength", "\"workingPair\": [1, 2]", "\"workingPair\": [1, 2, 3]",
                      "workingPair: expected 2 gyro ids, got 3"},
        BadConfigCase{"NegativeSigma",
                      "\"modelSigma\": {\"k0DegH\": 0.3,  \"c1DegH\": [0.1,0.1,0.1]",
                      "\"modelSigma\": {\"k0DegH\": -0.3,  \"c1DegH\": [0.1,0.1,0.1]",
                      "gyros[0].modelSigma.k0DegH: -0.3 is outside [0, 10] deg/h"},
        BadConfigCase{"NegativeNoise", "[5, 5, 30]", "[5, -5, 30]", "starTracker.noiseArcsec"},
        BadConfigCase{"BasisTermUnknownKind", "\"model\":      {\"k0DegH\": 0.25},",
                      "\"model\": {\"k0DegH\": 0.25}, \"basisTerms\": [{\"kind\": \"ramp\", "
                      "\"axis\": 1}, {\"kind\": \"wobble\", \"axis\": 1}],",
                      "gyros[2].basisTerms[1].kind: unknown basis kind \"wobble\""},
        BadConfigCase{"BasisTermAxisOutOfRange", "\"model\":      {\"k0DegH\": 0.25},",
                      "\"model\": {\"k0DegH\": 0.25}, \"basisTerms\": [{\"kind\": \"ramp\", "
                      "\"axis\": 1}, {\"kind\": \"ramp\", \"axis\": 4}],",
                      "gyros[2].basisTerms[1].axis: must be 1..3, got 4"},
        BadConfigCase{"BasisTermValueBeyondLimit", "\"model\":      {\"k0DegH\": 0.25},",
                      "\"model\": {\"k0DegH\": 0.25}, \"basisTerms\": [{\"kind\": "
                      "\"spin_axis_harmonic\", \"axis\": 1, \"valueDegH\": 12}],",
                      "gyros[2].basisTerms[0].valueDegH: 12 deg/h is 12 deg/h at a unit "
                      "regressor, outside [-10, 10]"},
        BadConfigCase{"ExponentialDecayWithoutTimeConstant", "\"model\":      {\"k0DegH\": 0.25},",
                      "\"model\": {\"k0DegH\": 0.25}, \"basisTerms\": [{\"kind\": "
                      "\"exponential_decay\", \"axis\": 1, \"valueDegH\": 0.1}],",
                      "gyros[2].basisTerms[0].timeConstantS: 0 s is outside [60, 3.16224e+07] s"},
        BadConfigCase{"ReadoutDistortionWrongLength", "\"model\":      {\"k0DegH\": 0.25},",
                      "\"model\": {\"k0DegH\": 0.25}, \"readoutDistortion\": [0, 0, 0],",
                      "gyros[2].readoutDistortion: expected 9 values (D row-major) or none, got 3"},
        BadConfigCase{"ReadoutDistortionNotSymmetric", "\"model\":      {\"k0DegH\": 0.25},",
                      "\"model\": {\"k0DegH\": 0.25}, \"readoutDistortion\": "
                      "[0, 0.001, 0, 0, 0, 0, 0, 0, 0],",
                      "gyros[2].readoutDistortion[1]: 0.001 differs from its transpose entry [3]"},
        BadConfigCase{"ReadoutDistortionTooLarge", "\"model\":      {\"k0DegH\": 0.25},",
                      "\"model\": {\"k0DegH\": 0.25}, \"readoutDistortion\": "
                      "[0.02, 0, 0, 0, 0, 0, 0, 0, 0],",
                      "gyros[2].readoutDistortion[0]: 0.02 is outside [-0.01, 0.01]"},
        BadConfigCase{"EmptySpacecraftId", "\"RDK-1\"", "\"\"", "spacecraftId: must not be empty"},
        BadConfigCase{"SpacecraftIdWithNewline", "\"RDK-1\"", "\"RDK-1\\n\"",
                      "spacecraftId: character '\\n' at index 5"},
        BadConfigCase{"SpacecraftIdWithTerminalEscape", "\"RDK-1\"", "\"RDK\\u001b[2J\"",
                      "spacecraftId: character '\\x1b' at index 3"},
        BadConfigCase{"SpacecraftIdTooLong", "\"RDK-1\"", "\"" + std::string(65, 'R') + "\"",
                      "spacecraftId: 65 characters"},
        BadConfigCase{"ReportedIntegrationRate", "\"randomWalkDegHSqrtH\": 0.002",
                      "\"randomWalkDegHSqrtH\": 0.002, \"filter\": {\"integrationRateHz\": 3e7}",
                      "filter.integrationRateHz: 3e+07 is outside [0.1, 100] Hz (the propagation "
                      "step must resolve"},
        BadConfigCase{"InnovationKdBelowTwo", "\"randomWalkDegHSqrtH\": 0.002",
                      "\"randomWalkDegHSqrtH\": 0.002, \"filter\": {\"innovationKd\": 1.5}",
                      "filter.innovationKd: 1.5 is outside [2, 20] 1"},
        BadConfigCase{"DriftCoefficientTooLarge", "\"c1DegH\": [0.05,-0.02,0.01]",
                      "\"c1DegH\": [0.05,-0.02,11]",
                      "gyros[1].model.c1DegH[2]: 11 is outside [-10, 10] deg/h"},
        BadConfigCase{"RandomWalkTooLarge", "\"randomWalkDegHSqrtH\": 0.002",
                      "\"randomWalkDegHSqrtH\": 2", "randomWalkDegHSqrtH: 2 is outside [0, 1]"},
        BadConfigCase{"KeyedCoefficientUnknownTerm", "\"model\":      {\"k0DegH\": 0.25},",
                      "\"model\": {\"coefficients\": [{\"term\": \"k0\", \"valueDegH\": 0.25}, "
                      "{\"term\": \"c1\", \"valueDegH\": 0.1}]},",
                      "gyros[2].model.coefficients[1].term: unknown term \"c1\" (terms: k0, c1x, "
                      "c1y, c1z, c2x, c2y, c2z, mu12, mu23, mu31, nu23, nu31, nu12)"},
        BadConfigCase{"KeyedCoefficientGivenTwice", "\"model\":      {\"k0DegH\": 0.25},",
                      "\"model\": {\"coefficients\": [{\"term\": \"mu23\", \"valueDegH\": 0.1}, "
                      "{\"term\": \"k0\", \"valueDegH\": 0.25}, "
                      "{\"term\": \"mu23\", \"valueDegH\": 0.1}]},",
                      "gyros[2].model.coefficients[2].term: term \"mu23\" is given twice"},
        BadConfigCase{"KeyedCoefficientAlsoGivenByItsField", "\"model\":      {\"k0DegH\": 0.25},",
                      "\"model\": {\"c1DegH\": [0, 0, 0], "
                      "\"coefficients\": [{\"term\": \"c1y\", \"valueDegH\": 0.1}]},",
                      "gyros[2].model.coefficients[0].term: term \"c1y\" is also given by "
                      "gyros[2].model.c1DegH; give it once"},
        // A keyed coefficient out of range is named where it was written, not by its field.
        BadConfigCase{"KeyedCoefficientTooLarge", "\"model\":      {\"k0DegH\": 0.25},",
                      "\"model\": {\"coefficients\": [{\"term\": \"k0\", \"valueDegH\": 0.25}, "
                      "{\"term\": \"c1y\", \"valueDegH\": 0.1}, "
                      "{\"term\": \"nu31\", \"valueDegH\": -11}]},",
                      "gyros[2].model.coefficients[2].valueDegH: -11 is outside [-10, 10] deg/h"},
        BadConfigCase{
            "KeyedSigmaNegative", kGyro3Sigma,
            "{\"k0DegH\": 0.25},\n     \"modelSigma\": {\"coefficients\": [{\"term\": "
            "\"k0\", \"valueDegH\": 0.3}, {\"term\": \"c2z\", \"valueDegH\": -0.1}]}}",
            "gyros[2].modelSigma.coefficients[1].valueDegH: -0.1 is outside [0, 10] deg/h"},
        BadConfigCase{
            "KeyedSigmaTooSmallForAVariance", kGyro3Sigma,
            "{\"k0DegH\": 0.25},\n     \"modelSigma\": {\"coefficients\": [{\"term\": "
            "\"mu12\", \"valueDegH\": 1e-160}]}}",
            "gyros[2].modelSigma.coefficients[0].valueDegH: 1e-160 deg/h is a prior sigma "
            "below about"},
        BadConfigCase{
            "KeyedSigmaUnderflowingToZero", kGyro3Sigma,
            "{\"k0DegH\": 0.25},\n     \"modelSigma\": {\"coefficients\": [{\"term\": "
            "\"mu12\", \"valueDegH\": 5e-324}]}}",
            "gyros[2].modelSigma.coefficients[0].valueDegH: 4.94066e-324 is a prior sigma "
            "too small to be represented in SI units"},
        // The same refusals of the deprecated fields name the field.
        BadConfigCase{"SigmaTooSmallForAVarianceByItsField", kGyro3Sigma,
                      "{\"k0DegH\": 0.25},\n     \"modelSigma\": {\"muDegH\": [1e-160, 0, 0]}}",
                      "gyros[2].modelSigma.muDegH[0]: 1e-160 deg/h is a prior sigma below about"},
        BadConfigCase{"WrongJsonType", "\"k0DegH\": 0.25", "\"k0DegH\": \"fast\"",
                      "gyros[2].model.k0DegH: invalid value \"fast\""},
        BadConfigCase{"WrongJsonTypeInArray", "\"workingPair\": [1, 2]",
                      "\"workingPair\": [1, 2.5]", "workingPair[1]: invalid value 2.5"},
        BadConfigCase{"NotJson", "\"workingPair\": [1, 2],", "\"workingPair\" [1, 2],",
                      "config JSON"}),
    [](const ::testing::TestParamInfo<BadConfigCase>& info) { return info.param.name; });

// ---------------------------------------------------------------------------------------------
// Telemetry frames.

estimator::TelemetryFrame SampleFrame() {
  estimator::TelemetryFrame f;
  f.time = absl::FromUnixSeconds(1551398400) + absl::Nanoseconds(123456789);
  estimator::GyroReading g1;
  g1.h_k = Eigen::Vector3d(0.3, -0.4, 0.8).normalized();
  g1.u_k_mv = Eigen::Vector3d(12.5, -33.25, 0.125);
  estimator::GyroReading g3;
  g3.h_k = Eigen::Vector3d(-0.1, 0.99, 0.07).normalized();  // no voltages telemetered
  estimator::GyroReading g4;
  g4.h_k = Eigen::Vector3d(0.577, 0.577, -0.578).normalized();
  g4.u_k_mv = Eigen::Vector3d(-1.0 / 3.0, 2.0 / 7.0, 1e-9);
  f.gyros[0] = g1;
  f.gyros[2] = g3;
  f.gyros[3] = g4;
  estimator::StarTrackerReading st;
  st.valid = true;
  st.q_in_b = Eigen::Quaterniond(0.9, -0.1, 0.3, 0.2).normalized();
  f.star_tracker = st;
  return f;
}

void ExpectFramesEqual(const estimator::TelemetryFrame& a, const estimator::TelemetryFrame& b) {
  EXPECT_EQ(a.time, b.time);
  for (int i = 0; i < estimator::kMaxGyros; ++i) {
    ASSERT_EQ(a.gyros[i].has_value(), b.gyros[i].has_value()) << "gyro " << i + 1;
    if (!a.gyros[i].has_value()) continue;
    EXPECT_EQ(a.gyros[i]->h_k, b.gyros[i]->h_k) << "gyro " << i + 1;
    ASSERT_EQ(a.gyros[i]->u_k_mv.has_value(), b.gyros[i]->u_k_mv.has_value()) << "gyro " << i + 1;
    if (a.gyros[i]->u_k_mv.has_value()) {
      EXPECT_EQ(*a.gyros[i]->u_k_mv, *b.gyros[i]->u_k_mv);
    }
  }
  ASSERT_EQ(a.star_tracker.has_value(), b.star_tracker.has_value());
  if (a.star_tracker.has_value()) {
    EXPECT_EQ(a.star_tracker->valid, b.star_tracker->valid);
    if (a.star_tracker->valid) {
      EXPECT_EQ(a.star_tracker->q_in_b.coeffs(), b.star_tracker->q_in_b.coeffs());
    }
  }
}

TEST(Frame, RoundTripIsExact) {
  const estimator::TelemetryFrame original = SampleFrame();
  const esg::v1::TelemetryFrame proto = FrameToProto(original, "RDK-1", 42);
  EXPECT_EQ(proto.spacecraft_id(), "RDK-1");
  EXPECT_EQ(proto.sequence(), 42);
  ASSERT_EQ(proto.gyros_size(), 3);
  EXPECT_EQ(proto.gyros(1).gyro_id(), 3);
  EXPECT_TRUE(proto.gyros(1).u_k_mv().empty());
  // Scalar first on the wire.
  ASSERT_EQ(proto.star_tracker().q_in_b_size(), 4);
  EXPECT_EQ(proto.star_tracker().q_in_b(0), original.star_tracker->q_in_b.w());
  EXPECT_EQ(proto.star_tracker().q_in_b(3), original.star_tracker->q_in_b.z());
  absl::StatusOr<estimator::TelemetryFrame> back = FrameFromProto(proto);
  ASSERT_THAT(back, IsOk());
  ExpectFramesEqual(original, *back);
}

TEST(Frame, OutageAndInvalidStarTrackerRoundTrip) {
  estimator::TelemetryFrame outage = SampleFrame();
  outage.star_tracker.reset();
  const esg::v1::TelemetryFrame outage_proto = FrameToProto(outage, "RDK-1", 1);
  EXPECT_FALSE(outage_proto.has_star_tracker());
  absl::StatusOr<estimator::TelemetryFrame> outage_back = FrameFromProto(outage_proto);
  ASSERT_THAT(outage_back, IsOk());
  EXPECT_FALSE(outage_back->star_tracker.has_value());

  estimator::TelemetryFrame invalid = SampleFrame();
  invalid.star_tracker->valid = false;
  const esg::v1::TelemetryFrame invalid_proto = FrameToProto(invalid, "RDK-1", 2);
  EXPECT_TRUE(invalid_proto.has_star_tracker());
  EXPECT_TRUE(invalid_proto.star_tracker().q_in_b().empty());
  absl::StatusOr<estimator::TelemetryFrame> invalid_back = FrameFromProto(invalid_proto);
  ASSERT_THAT(invalid_back, IsOk());
  ASSERT_TRUE(invalid_back->star_tracker.has_value());
  EXPECT_FALSE(invalid_back->star_tracker->valid);
}

TEST(Frame, SlightlyNonUnitVectorsAreAcceptedAndRenormalised) {
  esg::v1::TelemetryFrame proto = FrameToProto(SampleFrame(), "RDK-1", 3);
  for (double& v : *proto.mutable_gyros(0)->mutable_h_k()) v *= 1.0005;
  for (double& v : *proto.mutable_star_tracker()->mutable_q_in_b()) v *= 0.9995;
  absl::StatusOr<estimator::TelemetryFrame> frame = FrameFromProto(proto);
  ASSERT_THAT(frame, IsOk());
  EXPECT_NEAR(frame->gyros[0]->h_k.norm(), 1.0, 1e-15);
  EXPECT_NEAR(frame->star_tracker->q_in_b.norm(), 1.0, 1e-15);
}

TEST(Frame, InvalidStarTrackerQuaternionIsNotCarriedButMustBeNumbers) {
  esg::v1::TelemetryFrame proto = FrameToProto(SampleFrame(), "RDK-1", 3);
  proto.mutable_star_tracker()->set_valid(false);  // quaternion still present, not unit-checked
  for (double& v : *proto.mutable_star_tracker()->mutable_q_in_b()) v *= 3.0;
  EXPECT_THAT(FrameFromProto(proto), IsOk());
  proto.mutable_star_tracker()->set_q_in_b(1, std::nan(""));
  EXPECT_THAT(FrameFromProto(proto), StatusIs(absl::StatusCode::kInvalidArgument,
                                              HasSubstr("star_tracker.q_in_b[1]: nan is not finite")));
}

struct BadFrameCase {
  std::string name;
  std::function<void(esg::v1::TelemetryFrame*)> mutate;
  std::string expected_message;
};

void PrintTo(const BadFrameCase& c, std::ostream* os) { *os << c.name; }

class BadFrame : public ::testing::TestWithParam<BadFrameCase> {};

TEST_P(BadFrame, IsInvalidArgumentNamingTheField) {
  esg::v1::TelemetryFrame proto = FrameToProto(SampleFrame(), "RDK-1", 7);
  ASSERT_THAT(FrameFromProto(proto), IsOk());
  GetParam().mutate(&proto);
  EXPECT_THAT(FrameFromProto(proto), StatusIs(absl::StatusCode::kInvalidArgument,
                                              HasSubstr(GetParam().expected_message)));
}

INSTANTIATE_TEST_SUITE_P(
    Frame, BadFrame,
    ::testing::Values(
        BadFrameCase{"MissingTime", [](esg::v1::TelemetryFrame* f) { f->clear_time(); },
                     "time: missing"},
        BadFrameCase{"EmptySpacecraftId",
                     [](esg::v1::TelemetryFrame* f) { f->clear_spacecraft_id(); },
                     "spacecraft_id: must not be empty"},
        BadFrameCase{"SpacecraftIdWithNewline",
                     [](esg::v1::TelemetryFrame* f) { f->set_spacecraft_id("RDK-1\nFAKE LOG LINE"); },
                     "spacecraft_id: character '\\n' at index 5 of \"RDK-1\\nFAKE LOG LINE\""},
        BadFrameCase{"SpacecraftIdWithTerminalEscape",
                     [](esg::v1::TelemetryFrame* f) { f->set_spacecraft_id("RDK\x1b[2J"); },
                     "spacecraft_id: character '\\x1b' at index 3"},
        BadFrameCase{"SpacecraftIdTooLong",
                     [](esg::v1::TelemetryFrame* f) { f->set_spacecraft_id(std::string(65, 'R')); },
                     "spacecraft_id: 65 characters"},
        BadFrameCase{"NanosOutOfRange",
                     [](esg::v1::TelemetryFrame* f) { f->mutable_time()->set_nanos(1000000000); },
                     "time: nanos 1000000000 is outside 0..999999999"},
        BadFrameCase{"HkNormTooLarge",
                     [](esg::v1::TelemetryFrame* f) {
                       auto* h = f->mutable_gyros(1)->mutable_h_k();
                       h->Set(0, 0.0);
                       h->Set(1, 1.2);
                       h->Set(2, 0.0);
                     },
                     "gyros[1].h_k: norm 1.2 is not 1 (tolerance 0.001)"},
        BadFrameCase{"HkWrongLength",
                     [](esg::v1::TelemetryFrame* f) { f->mutable_gyros(0)->mutable_h_k()->RemoveLast(); },
                     "gyros[0].h_k: expected 3 values, got 2"},
        BadFrameCase{"HkNaN",
                     [](esg::v1::TelemetryFrame* f) {
                       f->mutable_gyros(2)->set_h_k(2, std::numeric_limits<double>::quiet_NaN());
                     },
                     "gyros[2].h_k[2]: nan is not finite"},
        BadFrameCase{"UkInfinite",
                     [](esg::v1::TelemetryFrame* f) {
                       f->mutable_gyros(0)->set_u_k_mv(1, std::numeric_limits<double>::infinity());
                     },
                     "gyros[0].u_k_mv[1]: inf is not finite"},
        BadFrameCase{"UkWrongLength",
                     [](esg::v1::TelemetryFrame* f) { f->mutable_gyros(0)->add_u_k_mv(1.0); },
                     "gyros[0].u_k_mv: expected 3 values or none, got 4"},
        BadFrameCase{"GyroIdZero", [](esg::v1::TelemetryFrame* f) { f->mutable_gyros(1)->set_gyro_id(0); },
                     "gyros[1].gyro_id: 0 is outside 1..4"},
        BadFrameCase{"GyroIdFive", [](esg::v1::TelemetryFrame* f) { f->mutable_gyros(1)->set_gyro_id(5); },
                     "gyros[1].gyro_id: 5 is outside 1..4"},
        BadFrameCase{"GyroIdRepeated",
                     [](esg::v1::TelemetryFrame* f) { f->mutable_gyros(2)->set_gyro_id(1); },
                     "gyros[2].gyro_id: gyro 1 appears twice"},
        BadFrameCase{"QuaternionNotUnit",
                     [](esg::v1::TelemetryFrame* f) {
                       for (double& v : *f->mutable_star_tracker()->mutable_q_in_b()) v *= 0.5;
                     },
                     "star_tracker.q_in_b: norm 0.5 is not 1 (tolerance 0.001)"},
        BadFrameCase{"QuaternionThreeValues",
                     [](esg::v1::TelemetryFrame* f) {
                       f->mutable_star_tracker()->mutable_q_in_b()->RemoveLast();
                     },
                     "star_tracker.q_in_b: expected 4 values, got 3"},
        BadFrameCase{"QuaternionMissingWhenValid",
                     [](esg::v1::TelemetryFrame* f) { f->mutable_star_tracker()->clear_q_in_b(); },
                     "star_tracker.q_in_b: expected 4 values, got 0"}),
    [](const ::testing::TestParamInfo<BadFrameCase>& info) { return info.param.name; });

TEST(Frame, HugeSpacecraftIdIsRefusedFirstWithAShortPrintableMessage) {
  esg::v1::TelemetryFrame proto = FrameToProto(SampleFrame(), "RDK-1", 7);
  proto.set_spacecraft_id(std::string(8 << 20, '\n'));  // the reported 8 MB id, of newlines
  proto.clear_time();                                    // a second fault, reported after the id
  const absl::StatusOr<estimator::TelemetryFrame> frame = FrameFromProto(proto);
  ASSERT_THAT(frame, StatusIs(absl::StatusCode::kInvalidArgument,
                              ::testing::StartsWith("spacecraft_id: 8388608 characters")));
  const absl::string_view message = frame.status().message();
  EXPECT_LT(message.size(), 400u);
  for (const char c : message) {
    EXPECT_TRUE(c >= 0x20 && c < 0x7f) << "byte " << static_cast<int>(c) << " in the message";
  }
}

// Every example configuration shipped in deploy/examples passes the limits (the repository
// root from CMake, so the test runs from any directory).
TEST(ConfigFile, DeployExamplesAreValid) {
  const std::filesystem::path examples =
      std::filesystem::path(ESG_SOURCE_DIR) / "deploy" / "examples";
  ASSERT_TRUE(std::filesystem::is_directory(examples)) << examples;
  int read = 0;
  for (const auto& entry : std::filesystem::directory_iterator(examples)) {
    if (entry.path().extension() != ".json") continue;  // scenarios/ holds simulator files
    // Column mappings (docs/formats.md), tested by tests/formats/column_mapping_test.cc.
    if (entry.path().filename().string().rfind("columns_", 0) == 0) continue;
    EXPECT_THAT(ReadConfigFile(entry.path().string()), IsOk()) << entry.path();
    ++read;
  }
  EXPECT_GE(read, 1);
}

// ---------------------------------------------------------------------------------------------
// Time.

TEST(Time, RoundTripKeepsNanosecondsAndHandlesInstantsBefore1970) {
  for (const absl::Time t :
       {absl::FromUnixSeconds(1551398400) + absl::Nanoseconds(999999999),
        absl::FromUnixSeconds(-1) + absl::Nanoseconds(250), absl::UnixEpoch(),
        absl::FromUnixSeconds(-62135596800), absl::FromUnixSeconds(253402300799)}) {
    const google::protobuf::Timestamp ts = TimeToProto(t);
    EXPECT_GE(ts.nanos(), 0);
    EXPECT_LE(ts.nanos(), 999999999);
    absl::StatusOr<absl::Time> back = TimeFromProto(ts);
    ASSERT_THAT(back, IsOk());
    EXPECT_EQ(*back, t) << absl::FormatTime(t);
  }
  const google::protobuf::Timestamp before = TimeToProto(absl::FromUnixMillis(-1500));
  EXPECT_EQ(before.seconds(), -2);
  EXPECT_EQ(before.nanos(), 500000000);
}

TEST(Time, SubNanosecondIsTruncatedAndInfinitiesClamp) {
  const absl::Time t = absl::FromUnixSeconds(10) + absl::Nanoseconds(5) + absl::Nanoseconds(1) / 4;
  EXPECT_EQ(TimeToProto(t).nanos(), 5);
  EXPECT_EQ(TimeToProto(absl::InfiniteFuture()).seconds(), 253402300799);
  EXPECT_EQ(TimeToProto(absl::InfinitePast()).seconds(), -62135596800);
}

TEST(Time, OutOfRangeTimestampIsInvalid) {
  google::protobuf::Timestamp ts;
  ts.set_seconds(253402300800);
  EXPECT_THAT(TimeFromProto(ts), StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("seconds")));
  ts.set_seconds(0);
  ts.set_nanos(-1);
  EXPECT_THAT(TimeFromProto(ts), StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("nanos")));
}

TEST(DriftModel, ProtoRoundTripConvertsDegPerHour) {
  estimator::DriftCoefficients c;
  c.k0 = DegHToRadS(0.12);
  c.C1 = Eigen::Vector3d(DegHToRadS(0.1), 0.0, DegHToRadS(-0.05));
  const esg::v1::GyroDriftModel proto = DriftModelToProto(c);
  // Every coefficient keyed, in the table's order, zeros too; no field.
  ASSERT_EQ(proto.coefficients_size(), estimator::kNumDriftCoefficients);
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    EXPECT_EQ(proto.coefficients(term.theta_index).term(), term.storage_key);
    EXPECT_FALSE(GivenByAField(proto, term)) << term.label;
  }
  EXPECT_NEAR(DriftModelTermDegH(proto, estimator::kFixedTerms[estimator::kThetaK0]), 0.12, 1e-15);
  EXPECT_NEAR(DriftModelTermDegH(proto, estimator::kFixedTerms[estimator::kThetaC1 + 2]), -0.05,
              1e-15);
  absl::StatusOr<estimator::DriftCoefficients> back = DriftModelFromProto(proto, "sigma");
  ASSERT_THAT(back, IsOk());
  EXPECT_TRUE(back->AsVector().isApprox(c.AsVector(), 1e-15));
  // A deprecated field of the release before is still checked: 4 values of a vector.
  esg::v1::GyroDriftModel bad;
  ASSERT_TRUE(google::protobuf::util::JsonStringToMessage(R"({"nuDegH": [0, 0, 0, 0]})", &bad).ok());
  EXPECT_THAT(DriftModelFromProto(bad, "sigma"),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("sigma.nuDegH: expected 3 values, got 4")));
}

// A GyroDriftModel whose 13 coefficients are distinct, given by its deprecated fields (as the
// release before wrote it: a term added to the table later is not in it, 0); each value has more
// digits than the 15 DriftModelToProto keeps, so a read that rounded would show.
double DistinctDegH(const estimator::FixedTermDescriptor& term) {
  return (term.theta_index + 1) * (term.theta_index % 2 ? -1.0 : 1.0) / 7.0;
}
esg::v1::GyroDriftModel DistinctFieldModel() {
  esg::v1::GyroDriftModel proto;
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    if (FieldOf(term) != nullptr) SetByField(term, DistinctDegH(term), &proto);
  }
  return proto;
}
// The value DistinctFieldModel gives the term.
double DistinctFieldDegH(const estimator::FixedTermDescriptor& term) {
  return FieldOf(term) != nullptr ? DistinctDegH(term) : 0.0;
}

// The keyed form (GyroDriftModel.coefficients) reads as the fields do: every coefficient keyed, in
// reverse order, and half of them keyed with the other half in fields, give the same coefficients
// bit for bit.
TEST(DriftModel, KeyedCoefficientsReadAsTheirFieldsDo) {
  const esg::v1::GyroDriftModel fields = DistinctFieldModel();
  ASSERT_EQ(fields.coefficients_size(), 0);
  absl::StatusOr<estimator::DriftCoefficients> expected = DriftModelFromProto(fields, "model");
  ASSERT_THAT(expected, IsOk());

  esg::v1::GyroDriftModel keyed;
  for (int i = estimator::kNumDriftCoefficients - 1; i >= 0; --i) {
    esg::v1::DriftCoefficient* c = keyed.add_coefficients();
    c->set_term(std::string(estimator::kFixedTerms[i].storage_key));
    c->set_value_deg_h(DriftModelTermDegH(fields, estimator::kFixedTerms[i]));
  }
  absl::StatusOr<estimator::DriftCoefficients> all_keyed = DriftModelFromProto(keyed, "model");
  ASSERT_THAT(all_keyed, IsOk());
  EXPECT_EQ(all_keyed->AsVector(), expected->AsVector());

  // k0, C2 and nu keyed; C1 and mu in their fields.
  esg::v1::GyroDriftModel mixed;
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    if (term.symbol == "C1" || term.symbol == "mu") SetByField(term, DistinctDegH(term), &mixed);
  }
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    if (term.symbol != "k0" && term.symbol != "C2" && term.symbol != "nu") continue;
    esg::v1::DriftCoefficient* c = mixed.add_coefficients();
    c->set_term(std::string(term.storage_key));
    c->set_value_deg_h(DriftModelTermDegH(fields, term));
  }
  ASSERT_EQ(mixed.coefficients_size(), 7);
  absl::StatusOr<estimator::DriftCoefficients> half = DriftModelFromProto(mixed, "model");
  ASSERT_THAT(half, IsOk());
  EXPECT_EQ(half->AsVector(), expected->AsVector());
}

// In the configuration JSON: gyro 3's model keyed ("coefficients": [{"term": "k0", ...}]) reads as
// the example's "k0DegH", and a prior sigma keyed is a sigma (the coefficient is estimated).
TEST(ConfigJson, KeyedCoefficientsReadAsTheFieldsOfTheExample) {
  absl::StatusOr<estimator::SpacecraftConfig> fields = ParseConfigJson(kDesignJson);
  ASSERT_THAT(fields, IsOk());
  absl::StatusOr<estimator::SpacecraftConfig> keyed = ParseConfigJson(DesignJsonWith(
      "\"model\":      {\"k0DegH\": 0.25},\n"
      "     \"modelSigma\": {\"k0DegH\": 0.3,  \"c1DegH\": [0.1,0.1,0.1], "
      "\"c2DegH\": [0.1,0.1,0.1]}}\n",
      "\"model\": {\"coefficients\": [{\"term\": \"k0\", \"valueDegH\": 0.25}]},\n"
      "     \"modelSigma\": {\"coefficients\": [{\"term\": \"k0\", \"valueDegH\": 0.3}, "
      "{\"term\": \"c1x\", \"valueDegH\": 0.1}, {\"term\": \"c1y\", \"valueDegH\": 0.1}, "
      "{\"term\": \"c1z\", \"valueDegH\": 0.1}], \"c2DegH\": [0.1,0.1,0.1]}}\n"));
  ASSERT_THAT(keyed, IsOk());
  ASSERT_EQ(keyed->gyros.size(), 3u);
  EXPECT_EQ(keyed->gyros[2].model.AsVector(), fields->gyros[2].model.AsVector());
  EXPECT_EQ(keyed->gyros[2].model_sigma.AsVector(), fields->gyros[2].model_sigma.AsVector());
  EXPECT_EQ(keyed->gyros[2].model.k0, DegHToRadS(0.25));
  // Written back, both are the same text, every coefficient keyed (zeros too) and no field.
  const std::string written = ConfigToJson(*keyed);
  EXPECT_EQ(written, ConfigToJson(*fields));
  EXPECT_THAT(written, HasSubstr("{\"term\": \"nu12\", \"valueDegH\": 0}"));
  EXPECT_THAT(written, Not(HasSubstr("nuDegH")));
  absl::StatusOr<estimator::SpacecraftConfig> back = ParseConfigJson(written);
  ASSERT_THAT(back, IsOk());
  EXPECT_EQ(back->gyros[2].model.AsVector(), fields->gyros[2].model.AsVector());
  EXPECT_EQ(back->gyros[2].model_sigma.AsVector(), fields->gyros[2].model_sigma.AsVector());
}

// A term added to the table after the proto's fields (here one made up, past the 13 of theta) is
// written keyed like the 13, and read back from there.
TEST(DriftModel, ATermWithoutAFieldOfItsOwnIsWrittenAndReadKeyed) {
  const estimator::FixedTermDescriptor later = {
      "k1", "k1", "k1DegH", -1, "deg/h", "k", estimator::kNumDriftCoefficients, "k1",
      "a term added later", estimator::kModelPart10, ""};
  esg::v1::GyroDriftModel proto = DriftModelToProto(
      estimator::DriftCoefficients::FromVector(estimator::DriftVector::Constant(1e-6)));
  ASSERT_EQ(proto.coefficients_size(), estimator::kNumDriftCoefficients);
  const esg::v1::GyroDriftModel before = proto;
  EXPECT_EQ(DriftModelTermDegH(proto, later), 0.0);
  SetDriftModelTermDegH(later, 0.375, &proto);
  ASSERT_EQ(proto.coefficients_size(), estimator::kNumDriftCoefficients + 1);
  EXPECT_EQ(proto.coefficients(estimator::kNumDriftCoefficients).term(), "k1");
  EXPECT_EQ(DriftModelTermDegH(proto, later), 0.375);
  SetDriftModelTermDegH(later, -0.5, &proto);
  ASSERT_EQ(proto.coefficients_size(), estimator::kNumDriftCoefficients + 1);
  EXPECT_EQ(DriftModelTermDegH(proto, later), -0.5);
  // The 13 coefficients are where they were.
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    EXPECT_EQ(DriftModelTermDegH(proto, term), DriftModelTermDegH(before, term)) << term.label;
  }
}

// Setting a coefficient of a model given by its deprecated fields (the release before's form)
// keys every coefficient first: no term is then given both ways, and the others keep their values.
TEST(DriftModel, SettingACoefficientOfAModelGivenByItsFieldsKeysThemAll) {
  esg::v1::GyroDriftModel proto = DistinctFieldModel();
  const estimator::FixedTermDescriptor& c1y = estimator::kFixedTerms[estimator::kThetaC1 + 1];
  SetDriftModelTermDegH(c1y, 2.5, &proto);
  int with_field = 0;
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    with_field += FieldOf(term) != nullptr ? 1 : 0;
  }
  ASSERT_EQ(proto.coefficients_size(), with_field);
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    EXPECT_FALSE(GivenByAField(proto, term)) << term.label;
    EXPECT_EQ(DriftModelTermDegH(proto, term), &term == &c1y ? 2.5 : DistinctFieldDegH(term))
        << term.label;
  }
  EXPECT_THAT(DriftModelFromProto(proto, "model"), IsOk());
}

// ---------------------------------------------------------------------------------------------
// Auxiliary housekeeping channels (docs/formats.md "Channels").

TEST(Frame, ChannelsRoundTripExactly) {
  estimator::TelemetryFrame original = SampleFrame();
  original.channels.Set("T_gyro2", 301.125);
  original.channels.Set("heater_1", 1.0);
  original.channels.Set("bus.V", -1.0 / 3.0);
  const esg::v1::TelemetryFrame proto = FrameToProto(original, "RDK-1", 5);
  ASSERT_EQ(proto.channels_size(), 3);
  EXPECT_EQ(proto.channels().at("T_gyro2"), 301.125);
  absl::StatusOr<estimator::TelemetryFrame> back = FrameFromProto(proto);
  ASSERT_THAT(back, IsOk());
  ExpectFramesEqual(original, *back);
  EXPECT_EQ(back->channels, original.channels);
  // Through the wire bytes as well, and a frame without channels has none.
  esg::v1::TelemetryFrame parsed;
  ASSERT_TRUE(parsed.ParseFromString(proto.SerializeAsString()));
  back = FrameFromProto(parsed);
  ASSERT_THAT(back, IsOk());
  EXPECT_EQ(back->channels, original.channels);
  back = FrameFromProto(FrameToProto(SampleFrame(), "RDK-1", 6));
  ASSERT_THAT(back, IsOk());
  EXPECT_TRUE(back->channels.empty());
}

TEST(Frame, BadChannelsAreRefusedNamingTheChannel) {
  esg::v1::TelemetryFrame proto = FrameToProto(SampleFrame(), "RDK-1", 7);
  (*proto.mutable_channels())["T_gyro2"] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THAT(FrameFromProto(proto),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       ::testing::StartsWith("channels[\"T_gyro2\"]: nan is not finite")));
  proto.clear_channels();
  (*proto.mutable_channels())["T gyro"] = 1.0;
  EXPECT_THAT(FrameFromProto(proto),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       ::testing::StartsWith("channels[\"T gyro\"]: character ' ' at index 1")));
  proto.clear_channels();
  for (int i = 0; i <= estimator::kMaxChannels; ++i) {
    (*proto.mutable_channels())[absl::StrCat("c", i)] = 0.0;
  }
  EXPECT_THAT(FrameFromProto(proto),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       ::testing::StartsWith("channels: 65 channels, at most 64 in a frame")));
}

TEST(Frame, AFrameWithEveryChannelFitsTheFrameSizeLimit) {
  // docs/service.md "Ingest contract": a serialized frame of more than 8192 bytes is refused.
  estimator::TelemetryFrame frame = SampleFrame();
  frame.gyros[1] = frame.gyros[0];
  for (int i = 0; i < estimator::kMaxChannels; ++i) {
    std::string name = absl::StrCat("channel_", i);
    name.resize(estimator::kMaxChannelNameLength, 'x');
    frame.channels.Set(name, -1.0 / 3.0);
  }
  const esg::v1::TelemetryFrame proto =
      FrameToProto(frame, std::string(64, 'R'), (int64_t{1} << 53) - 1);
  EXPECT_LE(proto.ByteSizeLong(), 8192u);
  EXPECT_THAT(FrameFromProto(proto), IsOk());
}

TEST(ConfigJson, ChannelDeclarationsRoundTrip) {
  const std::string json = DesignJsonWith(
      "\"randomWalkDegHSqrtH\": 0.002",
      "\"randomWalkDegHSqrtH\": 0.002,\n"
      "  \"channels\": [{\"name\": \"T_gyro2\", \"unit\": \"K\", \"validMin\": 250,"
      " \"validMax\": 350, \"maxAgeS\": 600},\n"
      "               {\"name\": \"heater_1\", \"unit\": \"1\", \"validMin\": 0, \"validMax\": 1}]");
  absl::StatusOr<estimator::SpacecraftConfig> c = ParseConfigJson(json);
  ASSERT_THAT(c, IsOk());
  ASSERT_EQ(c->channels.size(), 2u);
  EXPECT_EQ(c->channels[0].name, "T_gyro2");
  EXPECT_EQ(c->channels[0].unit, "K");
  EXPECT_EQ(c->channels[0].valid_min, 250.0);
  EXPECT_EQ(c->channels[0].valid_max, 350.0);
  EXPECT_EQ(c->channels[0].max_age, absl::Minutes(10));
  EXPECT_EQ(c->channels[1].max_age, absl::ZeroDuration());
  const std::string written = ConfigToJson(*c);
  EXPECT_THAT(written, HasSubstr("\"maxAgeS\": 600"));
  absl::StatusOr<estimator::SpacecraftConfig> back = ParseConfigJson(written);
  ASSERT_THAT(back, IsOk()) << written;
  EXPECT_EQ(back->channels, c->channels);
  EXPECT_EQ(ConfigToJson(*back), written);
}

TEST(ConfigJson, AConfigurationWithoutChannelsPrintsAsBefore) {
  // The service tells a changed configuration from the same one by its stored text.
  absl::StatusOr<estimator::SpacecraftConfig> c = ParseConfigJson(kDesignJson);
  ASSERT_THAT(c, IsOk());
  const std::string json = ConfigToJson(*c);
  EXPECT_THAT(json, Not(HasSubstr("channels")));
  EXPECT_THAT(json, HasSubstr("\"driftChangeLimitDegH\": 1\n  }\n}"));
}

// A basis term of kind channel (docs/formats.md "BasisTerm"): it names a declared channel, its
// form and the reference value, and the lag's time constant; written back to the same JSON, and
// only a channel term carries the channel's fields.
std::string WithChannelTerm(absl::string_view term) {
  return DesignJsonWith(
      "\"model\":      {\"k0DegH\": 0.25},",
      absl::StrCat("\"model\": {\"k0DegH\": 0.25}, \"basisTerms\": [", term, "],"));
}
constexpr char kTGyro2[] =
    "\"randomWalkDegHSqrtH\": 0.002, \"channels\": [{\"name\": \"T_gyro2\", \"unit\": \"K\", "
    "\"validMin\": 250, \"validMax\": 350, \"maxAgeS\": 600}]";

TEST(ConfigJson, ChannelTermRoundTripsWithItsChannelFormReferenceAndLag) {
  const std::string json = absl::StrReplaceAll(
      WithChannelTerm(R"({"kind": "channel", "axis": 2, "channel": "T_gyro2", "channelForm": "lag",)"
                      R"( "timeConstantS": 2400, "referenceValue": 293.15, "valueDegH": 0.004,)"
                      R"( "sigmaDegH": 0.01})"),
      {{"\"randomWalkDegHSqrtH\": 0.002", kTGyro2}});
  absl::StatusOr<estimator::SpacecraftConfig> c = ParseConfigJson(json);
  ASSERT_THAT(c, IsOk());
  ASSERT_EQ(c->gyros[2].basis_terms.size(), 1u);
  const estimator::BasisTerm& t = c->gyros[2].basis_terms[0];
  EXPECT_EQ(t.kind, estimator::BasisKind::kChannel);
  EXPECT_EQ(t.channel, "T_gyro2");
  EXPECT_EQ(t.form, estimator::ChannelForm::kLag);
  EXPECT_EQ(t.time_constant, 2400.0);
  EXPECT_EQ(t.reference, 293.15);
  // deg/h per K: the JSON's unit of s is the channel's.
  EXPECT_NEAR(t.value, DegHToRadS(0.004), 1e-22);
  EXPECT_NEAR(t.sigma, DegHToRadS(0.01), 1e-22);
  const std::string written = ConfigToJson(*c);
  EXPECT_THAT(written, HasSubstr("\"channel\": \"T_gyro2\""));
  EXPECT_THAT(written, HasSubstr("\"channelForm\": \"lag\""));
  EXPECT_THAT(written, HasSubstr("\"referenceValue\": 293.15"));
  EXPECT_THAT(written, HasSubstr("\"timeConstantS\": 2400"));
  absl::StatusOr<estimator::SpacecraftConfig> back = ParseConfigJson(written);
  ASSERT_THAT(back, IsOk()) << written;
  ExpectConfigsEqual(*c, *back);
  EXPECT_EQ(back->gyros[2].basis_terms[0].channel, "T_gyro2");
  EXPECT_EQ(back->gyros[2].basis_terms[0].form, estimator::ChannelForm::kLag);
  EXPECT_EQ(back->gyros[2].basis_terms[0].reference, 293.15);
  EXPECT_EQ(ConfigToJson(*back), written);
  // Through the proto message as the service stores it.
  const esg::v1::BasisTerm proto = BasisTermToProto(t);
  EXPECT_EQ(proto.channel(), "T_gyro2");
  EXPECT_EQ(proto.channel_form(), "lag");
  absl::StatusOr<estimator::BasisTerm> from = BasisTermFromProto(proto, "t");
  ASSERT_THAT(from, IsOk());
  EXPECT_EQ(from->channel, "T_gyro2");
  EXPECT_EQ(from->time_constant, 2400.0);
  EXPECT_EQ(from->reference, 293.15);
  // A value-form term carries no time constant; other kinds carry no channel fields.
  absl::StatusOr<estimator::SpacecraftConfig> value = ParseConfigJson(absl::StrReplaceAll(
      WithChannelTerm(R"({"kind": "channel", "axis": 1, "channel": "T_gyro2", "valueDegH": 0.004},)"
                      R"({"kind": "ramp", "axis": 1})"),
      {{"\"randomWalkDegHSqrtH\": 0.002", kTGyro2}}));
  ASSERT_THAT(value, IsOk());
  EXPECT_EQ(value->gyros[2].basis_terms[0].form, estimator::ChannelForm::kValue);
  const std::string value_json = ConfigToJson(*value);
  EXPECT_THAT(value_json, Not(HasSubstr("timeConstantS")));
  EXPECT_THAT(value_json, HasSubstr("\"channelForm\": \"value\""));
  EXPECT_EQ(BasisTermToJson(value->gyros[2].basis_terms[1]).find("channel"), std::string::npos);
}

TEST(ConfigJson, BadChannelTermsNameTheField) {
  auto parse = [](absl::string_view term, bool declared) {
    std::string json = WithChannelTerm(term);
    if (declared) json = absl::StrReplaceAll(json, {{"\"randomWalkDegHSqrtH\": 0.002", kTGyro2}});
    return ParseConfigJson(json);
  };
  EXPECT_THAT(parse(R"({"kind": "channel", "axis": 1, "channel": "T_gyro3"})", true),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("gyros[2].basisTerms[0].channel: \"T_gyro3\" is not declared in "
                                 "channels (declared: T_gyro2)")));
  EXPECT_THAT(parse(R"({"kind": "channel", "axis": 1, "channel": "T_gyro2"})", false),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("gyros[2].basisTerms[0].channel: \"T_gyro2\" is not declared in "
                                 "channels (declared: none)")));
  EXPECT_THAT(parse(R"({"kind": "channel", "axis": 1})", true),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("gyros[2].basisTerms[0].channel: empty name")));
  EXPECT_THAT(parse(R"({"kind": "channel", "axis": 1, "channel": "T_gyro2", "channelForm": "lag"})",
                    true),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("gyros[2].basisTerms[0].timeConstantS: 0 s is outside [60, ")));
  EXPECT_THAT(parse(R"({"kind": "channel", "axis": 1, "channel": "T_gyro2",)"
                    R"( "channelForm": "derivative", "timeConstantS": 1e9})",
                    true),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("gyros[2].basisTerms[0].timeConstantS: 1e+09 s is outside")));
  EXPECT_THAT(parse(R"({"kind": "channel", "axis": 1, "channel": "T_gyro2", "channelForm": "lagged"})",
                    true),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("gyros[2].basisTerms[0].channelForm: unknown channel form "
                                 "\"lagged\"")));
}

TEST(ConfigJson, BadChannelDeclarationsNameTheField) {
  auto with = [](absl::string_view channel) {
    return ParseConfigJson(DesignJsonWith(
        "\"randomWalkDegHSqrtH\": 0.002",
        absl::StrCat("\"randomWalkDegHSqrtH\": 0.002, \"channels\": [", channel, "]")));
  };
  EXPECT_THAT(with(R"({"name": "T", "unit": "K", "validMin": 5, "validMax": 1})"),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       ::testing::StartsWith("channels[0].validMin: ")));
  EXPECT_THAT(with(R"({"name": "T", "validMax": 1})"),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       ::testing::StartsWith("channels[0].unit: ")));
  EXPECT_THAT(with(R"({"name": "T", "unit": "K", "maxAgeS": -1})"),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       ::testing::StartsWith("channels[0].maxAgeS: ")));
  EXPECT_THAT(with(R"({"name": "T", "unit": "K", "maxAgeS": "NaN"})"),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       ::testing::StartsWith("channels[0].maxAgeS: nan is not finite")));
  EXPECT_THAT(with(R"({"name": "", "unit": "K"})"),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       ::testing::StartsWith("channels[0].name: ")));
}

}  // namespace
}  // namespace esg::proto_convert
