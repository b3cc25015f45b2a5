// Input limits of the spacecraft configuration (estimator/spacecraft_config.h): the identifier
// rule, every range of kConfigLimits at and just beyond its bounds, caseToBody, and the session's
// refusal of a propagation whose step count would not fit an int.
#include "estimator/spacecraft_config.h"

#include <cmath>
#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"
#include "estimator/calibration_model.h"
#include "estimator/rotation.h"
#include "estimator/session.h"
#include "estimator/simulator.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/paper_setup.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator {
namespace {

using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::AllOf;
using ::testing::HasSubstr;
using ::testing::Not;
using ::testing::StartsWith;

// True when every byte is printable ASCII (no control character, no byte >= 0x80).
bool PrintableAscii(absl::string_view s) {
  for (const char c : s) {
    const unsigned char u = static_cast<unsigned char>(c);
    if (u < 0x20 || u >= 0x7f) return false;
  }
  return true;
}

// ---------------------------------------------------------------------------------------------
// Identifier rule.

TEST(Identifier, IdsUsedByTheProjectAndEdgeCasesAreAccepted) {
  const std::vector<std::string> ids = {"RDK-1",     "SC-A", "TEST-1", "LOAD-99", "DISC-CLI",
                                        "E2E-1",     "X",    "0",      "a.b_c:d-e",
                                        "station_3", std::string(kMaxIdentifierLength, 'A')};
  for (const std::string& id : ids) {
    EXPECT_THAT(ValidateIdentifier(id, "spacecraftId"), IsOk()) << id;
  }
}

TEST(Identifier, RefusedValuesNameTheFieldAndTheRule) {
  struct Case {
    std::string value;
    std::string expected;  // substring of the message after "station_id: "
  };
  const Case cases[] = {
      {"", "must not be empty"},
      {std::string(kMaxIdentifierLength + 1, 'A'), "65 characters"},
      {"RDK-1\n", "character '\\n' at index 5"},
      {"RDK\x1b[31m", "character '\\x1b' at index 3"},
      {"RDK 1", "character ' ' at index 3"},
      {"RDK/1", "character '/' at index 3"},
      {"-RDK", "character '-' at index 0"},
      {".hidden", "character '.' at index 0"},
      {std::string("RD\0K", 4), "character '\\x00' at index 2"},
      {"RDK-1\xc3\xa9", "character '\\xc3' at index 5"},  // "RDK-1é" in UTF-8
      {"SAT-7 \"Zvezda\"", "character ' ' at index 5"},
  };
  for (const Case& c : cases) {
    const absl::Status s = ValidateIdentifier(c.value, "station_id");
    EXPECT_THAT(s, StatusIs(absl::StatusCode::kInvalidArgument,
                            AllOf(StartsWith("station_id: "), HasSubstr(c.expected))))
        << absl::CHexEscape(c.value);
    EXPECT_TRUE(PrintableAscii(s.message())) << absl::CHexEscape(s.message());
    if (!c.value.empty()) EXPECT_THAT(std::string(s.message()), HasSubstr("[A-Za-z0-9._:-]"));
  }
}

TEST(Identifier, MessageOfAHugeHostileValueIsShortAndPrintable) {
  for (const char fill : {'x', '\n', '\x1b', '\xff'}) {
    const std::string huge(1 << 20, fill);
    const absl::Status s = ValidateIdentifier(huge, "spacecraftId");
    ASSERT_FALSE(s.ok());
    EXPECT_THAT(std::string(s.message()),
                AllOf(StartsWith("spacecraftId: "), HasSubstr("1048576 characters")));
    EXPECT_LT(s.message().size(), 400u);  // 32 quoted characters, escaped to at most 4 bytes each
    EXPECT_TRUE(PrintableAscii(s.message())) << absl::CHexEscape(s.message());
  }
  // A bad character late in a value of legal length: still at most 32 characters quoted.
  const std::string late = std::string(60, 'A') + "\n";
  const absl::Status s = ValidateIdentifier(late, "spacecraft_id");
  EXPECT_THAT(std::string(s.message()), HasSubstr("at index 60 of \"" + std::string(32, 'A') + "\"..."));
  EXPECT_TRUE(PrintableAscii(s.message()));
}

TEST(Identifier, ValidateConfigAppliesItToSpacecraftId) {
  SpacecraftConfig c = testing::PaperConfig();
  ASSERT_THAT(ValidateConfig(c), IsOk());
  c.spacecraft_id = "RDK-1\n";
  EXPECT_THAT(ValidateConfig(c), StatusIs(absl::StatusCode::kInvalidArgument,
                                          StartsWith("spacecraftId: character '\\n' at index 5")));
  c.spacecraft_id = std::string(60 << 20, 'R');  // the reported 60 MB id
  const absl::Status s = ValidateConfig(c);
  EXPECT_THAT(s, StatusIs(absl::StatusCode::kInvalidArgument, StartsWith("spacecraftId: ")));
  EXPECT_LT(s.message().size(), 400u);
  c.spacecraft_id = "";
  EXPECT_THAT(ValidateConfig(c), StatusIs(absl::StatusCode::kInvalidArgument,
                                          HasSubstr("spacecraftId: must not be empty")));
}

// ---------------------------------------------------------------------------------------------
// Basis terms and readout distortion.

TEST(BasisTermsConfig, ErrorsNameTheGyroTheTermAndTheField) {
  SpacecraftConfig c = testing::PaperConfig();
  BasisTerm good;
  good.kind = BasisKind::kBodyRate;
  good.axis = 2;
  good.index = {3, 1};
  good.value = 0.01 / BasisValueToJson(BasisKind::kBodyRate);  // 0.01 deg/h per deg/s
  good.sigma = 1e-7;
  BasisTerm bad_axis = good;
  bad_axis.axis = 4;
  c.gyros[0].basis_terms = {good, bad_axis};
  EXPECT_THAT(ValidateConfig(c), StatusIs(absl::StatusCode::kInvalidArgument,
                                          StartsWith("gyros[0].basisTerms[1].axis: must be 1..3")));
  BasisTerm bad_index = good;
  bad_index.index = {0, 1};
  c.gyros[0].basis_terms = {good};
  c.gyros[2].basis_terms = {bad_index};
  EXPECT_THAT(ValidateConfig(c), StatusIs(absl::StatusCode::kInvalidArgument,
                                          StartsWith("gyros[2].basisTerms[0].index: ")));
  // The limit bounds the drift at the kind's reference size of its regressor (0.01 deg/s of body
  // rate): a body-rate term of 1100 deg/h per deg/s (11 deg/h at 0.01 deg/s) is refused, one of
  // 900 accepted.
  BasisTerm big = good;
  big.value = 1100.0 / BasisValueToJson(BasisKind::kBodyRate);
  c.gyros[2].basis_terms = {big};
  EXPECT_THAT(ValidateConfig(c),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       StartsWith("gyros[2].basisTerms[0].valueDegH: 1100 deg/h per deg/s is 11 "
                                  "deg/h at 0.01 deg/s of its regressor, outside [-10, 10]")));
  big.value = 900.0 / BasisValueToJson(BasisKind::kBodyRate);
  c.gyros[2].basis_terms = {big};
  EXPECT_THAT(ValidateConfig(c), IsOk());
  BasisTerm wide = good;
  wide.sigma = DegPerHourToRadPerSec(20.0);
  wide.kind = BasisKind::kSpinAxisHarmonic;
  c.gyros[2].basis_terms = {wide};
  EXPECT_THAT(ValidateConfig(c), StatusIs(absl::StatusCode::kInvalidArgument,
                                          StartsWith("gyros[2].basisTerms[0].sigmaDegH: 20 deg/h "
                                                     "is 20 deg/h at a unit regressor, "
                                                     "outside [0, 10]")));
  c.gyros[2].basis_terms.assign(kMaxBasisTermsPerGyro + 1, good);
  EXPECT_THAT(ValidateConfig(c), StatusIs(absl::StatusCode::kInvalidArgument,
                                          StartsWith("gyros[2].basisTerms: 17 terms, at most 16")));
  c.gyros[2].basis_terms.assign(kMaxBasisTermsPerGyro, good);
  EXPECT_THAT(ValidateConfig(c), IsOk());
}

// An exponential decay's time constant: a minute to a year, finite; its epoch where frame times
// may be (docs/formats.md "BasisTerm"); the field is named in the error.
TEST(BasisTermsConfig, ExponentialDecayNeedsATimeConstantInRange) {
  SpacecraftConfig c = testing::PaperConfig();
  BasisTerm decay;
  decay.kind = BasisKind::kExponentialDecay;
  decay.axis = 3;
  decay.time_constant = 4.0 * 3600.0;
  decay.epoch = absl::FromUnixSeconds(1551398400);
  decay.value = DegPerHourToRadPerSec(0.1);
  decay.sigma = DegPerHourToRadPerSec(0.2);
  c.gyros[1].basis_terms = {decay};
  EXPECT_THAT(ValidateConfig(c), IsOk());
  for (double tau_s : {0.0, -3600.0, 59.0, 367.0 * 86400.0,
                       std::numeric_limits<double>::quiet_NaN(),
                       std::numeric_limits<double>::infinity()}) {
    BasisTerm bad = decay;
    bad.time_constant = tau_s;
    c.gyros[1].basis_terms = {bad};
    EXPECT_THAT(ValidateConfig(c),
                StatusIs(absl::StatusCode::kInvalidArgument,
                         StartsWith("gyros[1].basisTerms[0].timeConstantS: ")))
        << tau_s;
  }
  BasisTerm early = decay;
  early.epoch = absl::UnixEpoch() - absl::Hours(1);
  c.gyros[1].basis_terms = {early};
  EXPECT_THAT(ValidateConfig(c), StatusIs(absl::StatusCode::kInvalidArgument,
                                          StartsWith("gyros[1].basisTerms[0].epoch: ")));
}

// s = exp(-(t - epoch) / tau) from the epoch on, 0 before it, along e_m (basis_term.h).
TEST(BasisTermsConfig, ExponentialDecayRegressorStartsAtItsEpochAndDecays) {
  BasisTerm decay;
  decay.kind = BasisKind::kExponentialDecay;
  decay.axis = 2;
  decay.time_constant = 4.0 * 3600.0;
  decay.epoch = absl::FromUnixSeconds(1551398400);
  decay.value = DegPerHourToRadPerSec(0.1);
  BasisInputs in;
  in.time = decay.epoch - absl::Seconds(1);
  EXPECT_EQ(BasisScalar(decay, in), 0.0);
  in.time = decay.epoch;
  EXPECT_EQ(BasisScalar(decay, in), 1.0);
  in.time = decay.epoch + absl::Hours(4);
  EXPECT_NEAR(BasisScalar(decay, in), std::exp(-1.0), 1e-15);
  in.time = decay.epoch + absl::Hours(8);
  const Eigen::Vector3d dw_k = BasisDrift_k(decay, in);
  EXPECT_NEAR(dw_k.y(), DegPerHourToRadPerSec(0.1) * std::exp(-2.0), 1e-20);
  EXPECT_EQ(dw_k.x(), 0.0);
  EXPECT_EQ(dw_k.z(), 0.0);
  EXPECT_EQ(BasisTermLabel(decay), "exp(-t/4h) -> y");
  EXPECT_EQ(BasisKindName(BasisKind::kExponentialDecay), "exponential_decay");
  EXPECT_THAT(ParseBasisKind("exponential_decay"), IsOk());
}

// A cycling harmonic, h1^a h2^b h3^c times cos or sin of 2 pi (t - epoch) / period (basis_term.h):
// the turning part of C1 or C2 of a rotor displacement that turns (eq. (10)); its period a minute
// to a year and its degree at most 4, the field named in the error.
TEST(BasisTermsConfig, CyclingHarmonicIsAHarmonicTimesItsPhaseAndChecksPeriodAndDegree) {
  BasisTerm cycle;
  cycle.kind = BasisKind::kCyclingHarmonic;
  cycle.axis = 1;
  cycle.exponents = {2, 0, 0};
  cycle.period = 24.0 * 3600.0;
  cycle.epoch = absl::FromUnixSeconds(1551398400);
  cycle.value = DegPerHourToRadPerSec(0.1);
  BasisInputs in;
  in.h_k = Eigen::Vector3d(0.6, 0.0, 0.8);
  in.time = cycle.epoch + absl::Hours(3);  // an eighth of the period
  EXPECT_NEAR(BasisScalar(cycle, in), 0.36 * std::cos(kPi / 4.0), 1e-15);
  cycle.sine = true;
  in.time = cycle.epoch + absl::Hours(30);  // 1.25 periods
  EXPECT_NEAR(BasisScalar(cycle, in), 0.36, 1e-12);
  in.time = cycle.epoch - absl::Hours(6);  // before the epoch: the phase runs backwards
  EXPECT_NEAR(BasisScalar(cycle, in), -0.36, 1e-12);
  const Eigen::Vector3d dw_k = BasisDrift_k(cycle, in);
  EXPECT_NEAR(dw_k.x(), -0.36 * DegPerHourToRadPerSec(0.1), 1e-20);
  EXPECT_EQ(dw_k.y(), 0.0);
  EXPECT_EQ(BasisTermLabel(cycle), "h1^2*cycle sin 24h -> x");
  cycle.exponents = {0, 0, 0};
  EXPECT_EQ(BasisTermLabel(cycle), "cycle sin 24h -> x");
  EXPECT_EQ(BasisKindName(BasisKind::kCyclingHarmonic), "cycling_harmonic");
  EXPECT_THAT(ParseBasisKind("cycling_harmonic"), IsOk());

  SpacecraftConfig c = testing::PaperConfig();
  c.gyros[0].basis_terms = {cycle};
  EXPECT_THAT(ValidateConfig(c), IsOk());
  for (double period_s : {0.0, -3600.0, 59.0, 367.0 * 86400.0,
                          std::numeric_limits<double>::quiet_NaN()}) {
    BasisTerm bad = cycle;
    bad.period = period_s;
    c.gyros[0].basis_terms = {bad};
    EXPECT_THAT(ValidateConfig(c), StatusIs(absl::StatusCode::kInvalidArgument,
                                            StartsWith("gyros[0].basisTerms[0].periodS: ")))
        << period_s;
  }
  BasisTerm deep = cycle;
  deep.exponents = {3, 2, 0};
  c.gyros[0].basis_terms = {deep};
  EXPECT_THAT(ValidateConfig(c), StatusIs(absl::StatusCode::kInvalidArgument,
                                          StartsWith("gyros[0].basisTerms[0].exponents: ")));
}

// A spin-axis term's regressor is h_1^a h_2^b h_3^c: with the powers tabulated once per substep
// (TabulateSpinAxisPowers, as a deviation series does) and without, it is the product of
// std::pow of each component, bit for bit, for every exponent combination up to the largest
// degree and for components of either sign.
TEST(BasisTermsConfig, SpinAxisTermsAreTheSameBitsWithTheirPowersTabulated) {
  const std::vector<Eigen::Vector3d> axes = {
      Eigen::Vector3d(0.6, 0.0, 0.8), Eigen::Vector3d(-0.3, 0.7, -0.2).normalized(),
      Eigen::Vector3d(0.123456789, -0.987654321, 0.5).normalized(), Eigen::Vector3d::UnitZ()};
  int compared = 0;
  for (const BasisKind kind : {BasisKind::kSpinAxisHarmonic, BasisKind::kCyclingHarmonic}) {
    for (int a = 0; a <= kMaxHarmonicDegree; ++a) {
      for (int b = 0; a + b <= kMaxHarmonicDegree; ++b) {
        for (int c = 0; a + b + c <= kMaxHarmonicDegree; ++c) {
          BasisTerm t;
          t.kind = kind;
          t.exponents = {a, b, c};
          t.period = 5400.0;
          for (const Eigen::Vector3d& h : axes) {
            BasisInputs in;
            in.time = absl::FromUnixSeconds(1551398400);
            in.h_k = h;
            const double phase = kind == BasisKind::kCyclingHarmonic
                                     ? std::cos(2.0 * kPi * std::fmod(1551398400.0, 5400.0) / 5400.0)
                                     : 1.0;
            const double expected =
                std::pow(h(0), a) * std::pow(h(1), b) * std::pow(h(2), c) * phase;
            const double direct = BasisScalar(t, in);
            TabulateSpinAxisPowers(in);
            ASSERT_TRUE(in.h_powers.has_value());
            EXPECT_EQ(BasisScalar(t, in), direct) << BasisTermLabel(t) << " at " << h.transpose();
            EXPECT_EQ(direct, expected) << BasisTermLabel(t) << " at " << h.transpose();
            ++compared;
          }
        }
      }
    }
  }
  EXPECT_EQ(compared, 2 * 35 * 4);  // 35 monomials of degree <= 4 in three variables
}

TEST(BasisTermsConfig, ReadoutDistortionMustBeSymmetricAndSmall) {
  SpacecraftConfig c = testing::PaperConfig();
  Eigen::Matrix3d D;
  D << 0.01, 1e-3, 0, 1e-3, -0.01, 0, 0, 0, 0;
  c.gyros[1].readout_distortion = D;
  EXPECT_THAT(ValidateConfig(c), IsOk());
  c.gyros[1].readout_distortion(0, 1) += 1e-11;
  EXPECT_THAT(ValidateConfig(c),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       StartsWith("gyros[1].readoutDistortion[1]: ")));
  c.gyros[1].readout_distortion = D;
  c.gyros[1].readout_distortion(2, 2) = 0.011;
  EXPECT_THAT(ValidateConfig(c), StatusIs(absl::StatusCode::kInvalidArgument,
                                          StartsWith("gyros[1].readoutDistortion[8]: 0.011 is "
                                                     "outside [-0.01, 0.01]")));
}

// ---------------------------------------------------------------------------------------------
// Numeric limits.

TEST(ConfigLimits, TableIsCompleteAndThePaperConfigurationIsWellInside) {
  for (const ConfigLimit& l : kConfigLimits.All()) {
    EXPECT_LT(l.min, l.max) << l.field;
    EXPECT_NE(std::string(l.reason), "") << l.field;
    EXPECT_NE(std::string(l.typical), "") << l.field;
    EXPECT_NE(std::string(l.unit), "") << l.field;
  }
  EXPECT_THAT(ValidateConfig(testing::PaperConfig()), IsOk());
  // The defaults of FilterConfig and SuspensionConfig are inside their limits by construction.
  const FilterConfig f;
  const SuspensionConfig s;
  EXPECT_THAT(CheckLimit(f.integration_rate_hz, kConfigLimits.integration_rate, "r"), IsOk());
  EXPECT_THAT(CheckLimit(f.measurement_step, kConfigLimits.measurement_step, "m"), IsOk());
  EXPECT_THAT(CheckLimit(f.innovation_kd, kConfigLimits.innovation_kd, "k"), IsOk());
  EXPECT_THAT(CheckLimit(s.amplifier_gain, kConfigLimits.amplifier_gain, "a"), IsOk());
  EXPECT_THAT(CheckLimit(s.reference_voltage, kConfigLimits.reference_voltage, "v"), IsOk());
  EXPECT_THAT(CheckLimit(s.gap, kConfigLimits.gap, "g"), IsOk());
  // The diagnosis runs the filter at 0.2 Hz with the eq. (12) test off (180 deg threshold).
  EXPECT_THAT(CheckLimit(0.2, kConfigLimits.integration_rate, "r"), IsOk());
  EXPECT_THAT(CheckLimit(kPi, kConfigLimits.fault_threshold, "t"), IsOk());
}

// One field of the configuration under one limit: sets the SI value.
struct LimitCase {
  std::string field;  // the JSON path the message must name
  const ConfigLimit* limit;
  double (*to_si)(double);  // limit's unit -> SI
  std::function<void(SpacecraftConfig&, double)> set;
};

void PrintTo(const LimitCase& c, std::ostream* os) { *os << c.field; }

double Same(double x) { return x; }
double UmToMetres(double x) { return x * kMetresPerUm; }

class LimitBound : public ::testing::TestWithParam<LimitCase> {};

TEST_P(LimitBound, BoundsAreAcceptedAndValuesJustBeyondAreRefusedNamingTheField) {
  const LimitCase& c = GetParam();
  const ConfigLimit& l = *c.limit;
  auto validate = [&](double value_in_unit) {
    SpacecraftConfig config = testing::PaperConfig();
    c.set(config, c.to_si(value_in_unit));
    return ValidateConfig(config);
  };
  // The bounds themselves, typed in the JSON's unit, pass the SI round trip.
  EXPECT_THAT(validate(l.min), IsOk()) << l.min;
  EXPECT_THAT(validate(l.max), IsOk()) << l.max;
  // 1e-6 (relative, or absolute at 0) beyond either bound is refused, naming the field.
  const double below = l.min - 1e-6 * std::max(std::abs(l.min), 1.0);
  const double above = l.max + 1e-6 * std::max(std::abs(l.max), 1.0);
  const auto named = AllOf(StartsWith(c.field + ": "), HasSubstr(" is outside ["),
                           HasSubstr(absl::StrCat("] ", l.unit, " (")));
  EXPECT_THAT(validate(below), StatusIs(absl::StatusCode::kInvalidArgument, named)) << below;
  EXPECT_THAT(validate(above), StatusIs(absl::StatusCode::kInvalidArgument, named)) << above;
  EXPECT_THAT(validate(std::numeric_limits<double>::quiet_NaN()),
              StatusIs(absl::StatusCode::kInvalidArgument, named));
  EXPECT_THAT(validate(std::numeric_limits<double>::infinity()),
              StatusIs(absl::StatusCode::kInvalidArgument, named));
}

const ConfigLimits& L = kConfigLimits;

INSTANTIATE_TEST_SUITE_P(
    ConfigLimits, LimitBound,
    ::testing::Values(
        LimitCase{"gyros[0].model.k0DegH", &L.drift_coefficient, &DegPerHourToRadPerSec,
                  [](SpacecraftConfig& c, double v) { c.gyros[0].model.k0 = v; }},
        LimitCase{"gyros[1].model.c1DegH[2]", &L.drift_coefficient, &DegPerHourToRadPerSec,
                  [](SpacecraftConfig& c, double v) { c.gyros[1].model.C1[2] = v; }},
        LimitCase{"gyros[2].model.c2DegH[0]", &L.drift_coefficient, &DegPerHourToRadPerSec,
                  [](SpacecraftConfig& c, double v) { c.gyros[2].model.C2[0] = v; }},
        LimitCase{"gyros[3].model.muDegH[1]", &L.drift_coefficient, &DegPerHourToRadPerSec,
                  [](SpacecraftConfig& c, double v) { c.gyros[3].model.mu[1] = v; }},
        LimitCase{"gyros[0].model.nuDegH[2]", &L.drift_coefficient, &DegPerHourToRadPerSec,
                  [](SpacecraftConfig& c, double v) { c.gyros[0].model.nu[2] = v; }},
        LimitCase{"gyros[0].modelSigma.k0DegH", &L.drift_sigma, &DegPerHourToRadPerSec,
                  [](SpacecraftConfig& c, double v) { c.gyros[0].model_sigma.k0 = v; }},
        LimitCase{"gyros[1].modelSigma.c1DegH[0]", &L.drift_sigma, &DegPerHourToRadPerSec,
                  [](SpacecraftConfig& c, double v) { c.gyros[1].model_sigma.C1[0] = v; }},
        LimitCase{"gyros[2].modelSigma.c2DegH[1]", &L.drift_sigma, &DegPerHourToRadPerSec,
                  [](SpacecraftConfig& c, double v) { c.gyros[2].model_sigma.C2[1] = v; }},
        LimitCase{"gyros[3].modelSigma.nuDegH[1]", &L.drift_sigma, &DegPerHourToRadPerSec,
                  [](SpacecraftConfig& c, double v) { c.gyros[3].model_sigma.nu[1] = v; }},
        LimitCase{"gyros[2].misalignmentSigmaArcsec", &L.misalignment_sigma, &ArcsecToRad,
                  [](SpacecraftConfig& c, double v) { c.gyros[2].misalignment_sigma = v; }},
        LimitCase{"starTracker.noiseArcsec[0]", &L.star_tracker_noise, &ArcsecToRad,
                  [](SpacecraftConfig& c, double v) { c.star_tracker.noise[0] = v; }},
        LimitCase{"starTracker.noiseArcsec[1]", &L.star_tracker_noise, &ArcsecToRad,
                  [](SpacecraftConfig& c, double v) { c.star_tracker.noise[1] = v; }},
        LimitCase{"starTracker.noiseArcsec[2]", &L.star_tracker_noise, &ArcsecToRad,
                  [](SpacecraftConfig& c, double v) { c.star_tracker.noise[2] = v; }},
        LimitCase{"readoutNoiseArcsec", &L.readout_noise, &ArcsecToRad,
                  [](SpacecraftConfig& c, double v) { c.readout_noise = v; }},
        LimitCase{"randomWalkDegHSqrtH", &L.random_walk, &DegPerHourSqrtHourToSi,
                  [](SpacecraftConfig& c, double v) { c.random_walk = v; }},
        LimitCase{"suspension.amplifierGain", &L.amplifier_gain, &Same,
                  [](SpacecraftConfig& c, double v) { c.suspension.amplifier_gain = v; }},
        LimitCase{"suspension.referenceVoltageV", &L.reference_voltage, &Same,
                  [](SpacecraftConfig& c, double v) { c.suspension.reference_voltage = v; }},
        LimitCase{"suspension.gapUm", &L.gap, &UmToMetres,
                  [](SpacecraftConfig& c, double v) { c.suspension.gap = v; }},
        LimitCase{"filter.integrationRateHz", &L.integration_rate, &Same,
                  [](SpacecraftConfig& c, double v) { c.filter.integration_rate_hz = v; }},
        LimitCase{"filter.measurementStepS", &L.measurement_step, &Same,
                  [](SpacecraftConfig& c, double v) { c.filter.measurement_step = v; }},
        LimitCase{"filter.innovationKd", &L.innovation_kd, &Same,
                  [](SpacecraftConfig& c, double v) { c.filter.innovation_kd = v; }},
        LimitCase{"filter.faultThresholdArcsec", &L.fault_threshold, &ArcsecToRad,
                  [](SpacecraftConfig& c, double v) { c.filter.fault_threshold = v; }},
        LimitCase{"filter.driftChangeLimitDegH", &L.drift_change_limit, &DegPerHourToRadPerSec,
                  [](SpacecraftConfig& c, double v) { c.filter.drift_change_limit = v; }}),
    [](const ::testing::TestParamInfo<LimitCase>& info) {
      std::string name;
      for (const char ch : info.param.field) {
        if (absl::ascii_isalnum(static_cast<unsigned char>(ch))) name += ch;
      }
      return name;
    });

TEST(ConfigLimits, ReportedIntegrationRateIsRefusedWithItsReason) {
  SpacecraftConfig c = testing::PaperConfig();
  c.filter.integration_rate_hz = 3e7;
  EXPECT_THAT(ValidateConfig(c),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       StartsWith("filter.integrationRateHz: 3e+07 is outside [0.1, 100] Hz (the "
                                  "propagation step must resolve")));
}

// A prior sigma is 0 (the state held) or has a normal variance: a positive one so small that its
// square underflows made the prior P0 zero or subnormal, and the session's relative sigma and
// checkpoint not finite (docs/fuzzing.md, finding 7).
TEST(ConfigLimits, APriorSigmaIsZeroOrHasANormalVariance) {
  const double tiny_si = 1e-160, small_si = 1e-150;  // square subnormal; square normal (1e-300)
  ASSERT_FALSE(std::isnormal(tiny_si * tiny_si));
  ASSERT_TRUE(std::isnormal(small_si * small_si));
  struct Field {
    const char* name;
    void (*set)(SpacecraftConfig&, double);
  };
  const Field fields[] = {
      {"gyros[1].modelSigma.c1DegH[2]: ",
       [](SpacecraftConfig& c, double v) { c.gyros[1].model_sigma.C1(2) = v; }},
      {"gyros[0].misalignmentSigmaArcsec: ",
       [](SpacecraftConfig& c, double v) { c.gyros[0].misalignment_sigma = v; }},
      {"starTracker.latencySigmaS: ",
       [](SpacecraftConfig& c, double v) { c.star_tracker.latency_sigma = v; }},
      {"gyros[2].basisTerms[0].sigmaDegH: ",
       [](SpacecraftConfig& c, double v) {
         BasisTerm t;
         t.kind = BasisKind::kSpinAxisHarmonic;  // degree 0: a case-fixed drift along axis 1
         t.sigma = v;
         c.gyros[2].basis_terms = {t};
       }},
  };
  for (const Field& f : fields) {
    for (double ok : {0.0, small_si}) {
      SpacecraftConfig c = testing::PaperConfig();
      f.set(c, ok);
      EXPECT_THAT(ValidateConfig(c), IsOk()) << f.name << ok;
    }
    SpacecraftConfig c = testing::PaperConfig();
    f.set(c, tiny_si);
    EXPECT_THAT(ValidateConfig(c),
                StatusIs(absl::StatusCode::kInvalidArgument,
                         AllOf(StartsWith(f.name), HasSubstr("use 0 to hold the state fixed"))));
  }
  SpacecraftConfig c = testing::PaperConfig();
  fields[0].set(c, tiny_si);
  EXPECT_THAT(ValidateConfig(c).message(),
              ::testing::Eq("gyros[1].modelSigma.c1DegH[2]: 2.06265e-155 deg/h is a prior sigma "
                            "below about 3.07679e-149 deg/h, whose variance is not a normal "
                            "double: use 0 to hold the state fixed, or a sigma of at least that"));
}

TEST(ConfigLimits, CaseToBodyMustBeAProperRotation) {
  SpacecraftConfig c = testing::PaperConfig();
  c.gyros[1].C_b_k(0, 0) += 1e-8;  // orthonormal to 1e-6: accepted
  EXPECT_THAT(ValidateConfig(c), IsOk());
  c.gyros[1].C_b_k(0, 0) += 1e-4;
  EXPECT_THAT(ValidateConfig(c), StatusIs(absl::StatusCode::kInvalidArgument,
                                          StartsWith("gyros[1].caseToBody: not a proper rotation")));
  c = testing::PaperConfig();
  c.gyros[2].C_b_k.row(2) *= -1.0;  // a reflection: orthonormal, det -1
  EXPECT_THAT(ValidateConfig(c), StatusIs(absl::StatusCode::kInvalidArgument,
                                          StartsWith("gyros[2].caseToBody: not a proper rotation")));
  c = testing::PaperConfig();
  c.gyros[0].C_b_k(1, 2) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THAT(ValidateConfig(c), StatusIs(absl::StatusCode::kInvalidArgument,
                                          StartsWith("gyros[0].caseToBody")));
}

// ---------------------------------------------------------------------------------------------
// The session does not rely on its caller to bound a frame gap: a step count beyond int is
// refused (it used to overflow static_cast<int>: undefined behaviour). At the fixed rate a
// 100-year gap is 2.5e10 steps; with the motion-bounded substeps (the default, D125) it is the
// turns' count and is propagated, while a frame at absl::InfiniteFuture is refused in both.

// The session after the first two frames of a 10-minute calibration flight, with `substeps`.
struct TwoFrames {
  SimulationSpec spec;
  std::vector<TelemetryFrame> frames;
  std::optional<EstimationSession> session;
};
TwoFrames AfterTwoFrames(SessionOptions::Substeps substeps) {
  TwoFrames t;
  t.spec.config = testing::PaperConfig();
  t.spec.duration = 600.0;
  t.spec.seed = 5;
  t.spec.profile = *MakeNamedProfile("calibration", t.spec.duration, t.spec.seed);
  absl::StatusOr<SimulationResult> sim = Simulate(t.spec);
  EXPECT_THAT(sim, IsOk());
  if (!sim.ok()) return t;
  t.frames = sim->recording.frames;
  EXPECT_GE(t.frames.size(), 3u);
  SessionOptions options;
  options.model = *ParseModel("10+11");
  options.substeps = substeps;
  absl::StatusOr<EstimationSession> session = EstimationSession::Create(t.spec.config, options);
  EXPECT_THAT(session, IsOk());
  if (!session.ok() || t.frames.size() < 3) return t;
  EXPECT_THAT(session->AddFrame(t.frames[0]), IsOk());
  EXPECT_THAT(session->AddFrame(t.frames[1]), IsOk());
  t.session = *std::move(session);
  return t;
}

TEST(SessionStepCount, AGapTooLongToCountInAnIntIsOutOfRangeAndLeavesTheSessionUnchanged) {
  TwoFrames t = AfterTwoFrames(SessionOptions::Substeps::kFixedRate);
  ASSERT_TRUE(t.session.has_value());
  EstimationSession& session = *t.session;
  const auto before = session.ExportCheckpoint().values;

  // 100 years at 8 Hz: 2.5e10 steps.
  TelemetryFrame far = t.frames[2];
  far.time = t.frames[1].time + absl::Hours(24 * 365 * 100);
  EXPECT_THAT(session.AddFrame(far),
              StatusIs(absl::StatusCode::kOutOfRange,
                       AllOf(HasSubstr("filter.integrationRateHz 8"), HasSubstr("steps"))));
  far.time = absl::InfiniteFuture();
  EXPECT_THAT(session.AddFrame(far), StatusIs(absl::StatusCode::kOutOfRange, HasSubstr("steps")));
  EXPECT_EQ(session.ExportCheckpoint().values, before);
  EXPECT_THAT(session.AddFrame(t.frames[2]), IsOk());  // still usable
}

// Motion-bounded: the span at absl::InfiniteFuture gives a motion that is not finite, which
// falls back to the fixed rate's count and is refused as above (it used to be dropped by
// std::max, the count taken from the readings' turn alone, and the propagation failed with a
// covariance that is not finite); a 100-year gap is propagated in fewer substeps than int holds.
TEST(SessionStepCount, MotionBoundedRefusesAnInfiniteSpanAndPropagatesACenturyGap) {
  TwoFrames t = AfterTwoFrames(SessionOptions::Substeps::kMotionBounded);
  ASSERT_TRUE(t.session.has_value());
  EstimationSession& session = *t.session;
  const auto before = session.ExportCheckpoint().values;

  TelemetryFrame far = t.frames[2];
  far.time = absl::InfiniteFuture();
  EXPECT_THAT(session.AddFrame(far), StatusIs(absl::StatusCode::kOutOfRange, HasSubstr("steps")));
  EXPECT_EQ(session.ExportCheckpoint().values, before);
  EXPECT_THAT(session.AddFrame(t.frames[2]), IsOk());  // still usable

  far.time = t.frames[2].time + absl::Hours(24 * 365 * 100);
  EXPECT_THAT(session.AddFrame(far), IsOk());
  EXPECT_GE(session.last_propagation_substeps(), 1);
  for (const GyroEstimate& g : session.Gyros()) {
    EXPECT_TRUE(g.sigma.AsVector().allFinite()) << "gyro " << g.id;
  }
}

}  // namespace
}  // namespace esg::estimator
