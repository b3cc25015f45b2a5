// Proto <-> estimator conversions (see convert.h): configuration JSON and telemetry frames
// (docs/formats.md), drift model (docs/physics.md) and timestamps.
#include "proto/convert.h"

#include <array>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <sstream>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/ascii.h"
#include "absl/strings/escaping.h"
#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_replace.h"
#include "estimator/channels.h"
#include "estimator/conventions.h"
#include "estimator/rotation.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"
#include "google/protobuf/descriptor.h"
#include "google/protobuf/descriptor.pb.h"
#include "google/protobuf/message.h"
#include "google/protobuf/repeated_field.h"
#include "google/protobuf/util/json_util.h"
#include "proto/strict_json.h"

namespace esg::proto_convert {

namespace {

using ::google::protobuf::RepeatedField;

// Abseil 20220623 in Debian has its own absl::string_view (not std::string_view).
absl::string_view AbslView(std::string_view s) { return absl::string_view(s.data(), s.size()); }

absl::Status FieldError(absl::string_view field, absl::string_view reason) {
  return absl::InvalidArgumentError(absl::StrCat(field, ": ", reason));
}

// The largest suspension offset voltage a frame may carry [mV]. eq. (3): the rotor displacement
// is k dU d0 / U0, and a displacement beyond the gap d0 would put the rotor on an electrode, so
// |dU| < U0 / k; with the configuration's widest bounds (U0 <= 10 kV, k >= 1) that is 10 kV.
// A larger value is a broken producer (1e308 mV made a suspension_voltage term's covariance
// non-finite).
const double kMaxSuspensionOffsetMv = estimator::kConfigLimits.reference_voltage.max /
                                      estimator::kConfigLimits.amplifier_gain.min /
                                      estimator::kVoltsPerMv;

// A prior sigma typed as a positive number must stay positive in SI: 5e-324 deg/h underflowed to 0
// (a held state) while 1e-200 deg/h was refused as a prior too small to be a variance
// (ValidateConfig). Both are refused, the first here, where the typed value is still known.
absl::Status SigmaKeptPositive(double json_value, double si_value, absl::string_view field) {
  if (json_value == 0.0 || si_value != 0.0) return absl::OkStatus();
  return FieldError(field, absl::StrFormat("%g is a prior sigma too small to be represented in SI "
                                           "units (it would read as 0, a held state): use 0 to "
                                           "hold the state, or a sigma the limits allow",
                                           json_value));
}

// A 3-vector that may be empty (zero).
absl::StatusOr<Eigen::Vector3d> OptionalVector3(const RepeatedField<double>& values,
                                               absl::string_view field) {
  if (values.empty()) return Eigen::Vector3d::Zero();
  if (values.size() != 3) {
    return FieldError(field, absl::StrFormat("expected 3 values, got %d", values.size()));
  }
  return Eigen::Vector3d(values[0], values[1], values[2]);
}

// Unit-converted values are written with 15 significant digits, so that a configuration file
// reads 0.12 rather than 0.11999999999999998 after deg/h -> rad/s -> deg/h (the SI value read back
// differs by at most 5e-16 relative, far below any physical meaning).
// A zero is written as 0: protobuf's JSON parser reads "-0" back as 0, so a written -0 would not
// read back to itself (found by fuzz_config_json).
double Tidy(double x) {
  if (x == 0.0) return 0.0;
  if (!std::isfinite(x)) return x;
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.15g", x);
  return std::strtod(buf, nullptr);
}

double TidyDegPerHour(double x) { return Tidy(estimator::RadPerSecToDegPerHour(x)); }
double TidyArcsec(double x) { return Tidy(estimator::RadToArcsec(x)); }

void SetVector3(const Eigen::Vector3d& v, RepeatedField<double>* out) {
  out->Clear();
  for (int i = 0; i < 3; ++i) out->Add(v[i]);
}

absl::StatusOr<std::array<int, 2>> Pair(const RepeatedField<int32_t>& values,
                                        absl::string_view field) {
  if (values.size() != 2) {
    return FieldError(field, absl::StrFormat("expected 2 gyro ids, got %d", values.size()));
  }
  return std::array<int, 2>{values[0], values[1]};
}

// Checks finiteness of every value, then the norm; renormalises beyond kRenormaliseAbove.
template <int N>
absl::StatusOr<Eigen::Matrix<double, N, 1>> UnitVector(const RepeatedField<double>& values,
                                                       absl::string_view field) {
  if (values.size() != N) {
    return FieldError(field, absl::StrFormat("expected %d values, got %d", N, values.size()));
  }
  Eigen::Matrix<double, N, 1> v;
  for (int i = 0; i < N; ++i) {
    if (!std::isfinite(values[i])) {
      return FieldError(absl::StrFormat("%s[%d]", field, i),
                        absl::StrFormat("%g is not finite", values[i]));
    }
    v[i] = values[i];
  }
  const double norm = v.norm();
  if (!(std::abs(norm - 1.0) <= kUnitNormTolerance)) {
    return FieldError(field, absl::StrFormat("norm %.6g is not 1 (tolerance %g)", norm,
                                             kUnitNormTolerance));
  }
  if (std::abs(norm - 1.0) > kRenormaliseAbove) v /= norm;
  return v;
}

absl::Status AllFinite(const RepeatedField<double>& values, absl::string_view field) {
  for (int i = 0; i < values.size(); ++i) {
    if (!std::isfinite(values[i])) {
      return FieldError(absl::StrFormat("%s[%d]", field, i),
                        absl::StrFormat("%g is not finite", values[i]));
    }
  }
  return absl::OkStatus();
}

// proto field path -> JSON path: "gyros[2].model.k0_deg_h" -> "gyros[2].model.k0DegH" (the
// default json_name rule: drop '_' and capitalise the next letter).
std::string JsonPath(absl::string_view proto_path) {
  std::string path;
  path.reserve(proto_path.size());
  bool capitalise = false;
  for (const char c : proto_path) {
    if (c == '_') {
      capitalise = true;
      continue;
    }
    path += capitalise ? absl::ascii_toupper(static_cast<unsigned char>(c)) : c;
    capitalise = false;
  }
  return path;
}

// Protobuf 3.21 messages name the field by its proto path in parentheses: an unknown field reads
// "(gyros[0]) bogus: Cannot find field." (no parentheses at the top level), a wrong type
// "(gyros[2].model.k0_deg_h): invalid value "fast" for type TYPE_DOUBLE". Both are rewritten to
// the "<JSON field>: <reason>" form of convert.h; other messages (syntax errors) are kept.
std::string JsonErrorMessage(const std::string& message) {
  constexpr absl::string_view kUnknown = ": Cannot find field.";
  const absl::string_view m(message);
  if (absl::EndsWith(m, kUnknown)) {
    absl::string_view head = m.substr(0, m.size() - kUnknown.size());
    std::string path;
    if (absl::StartsWith(head, "(")) {
      const size_t close = head.find(") ");
      if (close != absl::string_view::npos) {
        path = absl::StrCat(head.substr(1, close - 1), ".");
        head = head.substr(close + 2);
      }
    }
    return absl::StrCat(JsonPath(path), head, ": unknown field");
  }
  if (absl::StartsWith(m, "(")) {
    const size_t close = m.find("): ");
    if (close != absl::string_view::npos) {
      return absl::StrCat(JsonPath(m.substr(1, close - 1)), m.substr(close + 1));
    }
  }
  return absl::StrCat("config JSON: ", message);
}

// Re-indents protobuf's compact JSON: 2-space indent, one object member per line, arrays of
// numbers on one line ("caseToBody": [1, 0, 0, 0, 1, 0, 0, 0, 1]), as a human would write the
// configuration file (docs/formats.md). Input is protobuf's own output, hence valid JSON.
class JsonPrettyPrinter {
 public:
  explicit JsonPrettyPrinter(absl::string_view compact) : in_(compact) {}

  std::string Print() {
    Value(0);
    out_ += '\n';
    return std::move(out_);
  }

 private:
  void Indent(int depth) { out_.append(2 * depth, ' '); }

  // Copies a string token (with escapes) or a scalar.
  void Scalar() {
    if (in_[pos_] == '"') {
      const size_t start = pos_++;
      while (pos_ < in_.size() && in_[pos_] != '"') pos_ += in_[pos_] == '\\' ? 2 : 1;
      ++pos_;
      out_.append(in_.data() + start, pos_ - start);
      return;
    }
    const size_t start = pos_;
    while (pos_ < in_.size() && absl::string_view(",]}:").find(in_[pos_]) == absl::string_view::npos) ++pos_;
    out_.append(in_.data() + start, pos_ - start);
  }

  // True when the object or array starting at pos_ holds no object or array and at most
  // `max_commas` commas before its `close`: an array of scalars, or (max_commas 1) a keyed
  // coefficient, {"term": "c1x", "valueDegH": 0.02}; either is printed on one line. Text that
  // ends first is flat for an array, not for an object.
  bool Flat(char close, int max_commas) const {
    bool in_string = false;
    int commas = 0;
    for (size_t i = pos_ + 1; i < in_.size(); ++i) {
      const char c = in_[i];
      if (in_string) {
        if (c == '\\') ++i;
        else if (c == '"') in_string = false;
      } else if (c == '"') {
        in_string = true;
      } else if (c == '[' || c == '{') {
        return false;
      } else if (c == ',') {
        ++commas;
      } else if (c == close) {
        return commas <= max_commas;
      }
    }
    return close == ']';
  }

  // `in_array`: the value is an element of an array.
  void Value(int depth, bool in_array = false) {
    if (pos_ >= in_.size()) return;
    const char c = in_[pos_];
    if (c == '{' || c == '[') {
      const char close = c == '{' ? '}' : ']';
      const bool flat = c == '[' ? Flat(']', std::numeric_limits<int>::max())
                                 : in_array && Flat('}', 1);
      out_ += c;
      ++pos_;
      if (in_[pos_] == close) {
        out_ += close;
        ++pos_;
        return;
      }
      bool first = true;
      while (pos_ < in_.size()) {
        if (!first) out_ += flat ? ", " : ",";
        first = false;
        if (!flat) {
          out_ += '\n';
          Indent(depth + 1);
        }
        if (c == '{') {
          Scalar();  // key
          ++pos_;    // ':'
          out_ += ": ";
        }
        Value(depth + 1, c == '[');
        if (in_[pos_] == ',') {
          ++pos_;
          continue;
        }
        break;
      }
      if (!flat) {
        out_ += '\n';
        Indent(depth);
      }
      out_ += close;
      ++pos_;
      return;
    }
    Scalar();
  }

  absl::string_view in_;
  size_t pos_ = 0;
  std::string out_;
};

// Timestamp limits: 0001-01-01T00:00:00Z and 9999-12-31T23:59:59.999999999Z.
constexpr int64_t kMinTimestampSeconds = -62135596800;
constexpr int64_t kMaxTimestampSeconds = 253402300799;

}  // namespace

// A basis term of the JSON (units of its field names, spacecraft_config.proto) in SI
// (estimator/basis_term.h); the ranges are ValidateConfig's, after the whole configuration is read.
absl::StatusOr<estimator::BasisTerm> BasisTermFromProto(const esg::v1::BasisTerm& proto,
                                                        const std::string& prefix) {
  estimator::BasisTerm t;
  if (proto.kind().empty()) return FieldError(absl::StrCat(prefix, ".kind"), "required");
  absl::StatusOr<estimator::BasisKind> kind = estimator::ParseBasisKind(proto.kind());
  if (!kind.ok()) return FieldError(absl::StrCat(prefix, ".kind"), kind.status().message());
  t.kind = *kind;
  t.axis = proto.axis();
  if (!proto.exponents().empty()) {
    if (proto.exponents_size() != 3) {
      return FieldError(absl::StrCat(prefix, ".exponents"),
                        absl::StrFormat("expected 3 values or none, got %d", proto.exponents_size()));
    }
    for (int i = 0; i < 3; ++i) t.exponents[i] = proto.exponents(i);
  }
  if (proto.index_size() > 2) {
    return FieldError(absl::StrCat(prefix, ".index"),
                      absl::StrFormat("expected 1 or 2 values, got %d", proto.index_size()));
  }
  for (int i = 0; i < proto.index_size(); ++i) t.index[i] = proto.index(i);
  t.harmonic = proto.harmonic() != 0 ? proto.harmonic() : 1;
  t.sine = proto.sine();
  t.period = proto.period_s();
  t.time_constant = proto.time_constant_s();
  t.channel = proto.channel();
  if (!proto.channel_form().empty()) {
    absl::StatusOr<estimator::ChannelForm> form = estimator::ParseChannelForm(proto.channel_form());
    if (!form.ok()) {
      return FieldError(absl::StrCat(prefix, ".channelForm"), form.status().message());
    }
    t.form = *form;
  }
  t.reference = proto.reference_value();
  if (proto.has_epoch()) {
    absl::StatusOr<absl::Time> epoch = TimeFromProto(proto.epoch());
    if (!epoch.ok()) return FieldError(absl::StrCat(prefix, ".epoch"), epoch.status().message());
    t.epoch = *epoch;
  }
  const double to_json = estimator::BasisValueToJson(t.kind);
  t.value = proto.value_deg_h() / to_json;
  t.sigma = proto.sigma_deg_h() / to_json;
  RETURN_IF_ERROR(
      SigmaKeptPositive(proto.sigma_deg_h(), t.sigma, absl::StrCat(prefix, ".sigmaDegH")));
  return t;
}

esg::v1::BasisTerm BasisTermToProto(const estimator::BasisTerm& t) {
  esg::v1::BasisTerm proto;
  proto.set_kind(std::string(estimator::BasisKindName(t.kind)));
  proto.set_axis(t.axis);
  for (int e : t.exponents) proto.add_exponents(e);
  // Only the indices the kind reads (one, two for a product), so the JSON shows no unused one.
  proto.add_index(t.index[0]);
  if (t.kind == estimator::BasisKind::kBodyRateProduct) proto.add_index(t.index[1]);
  proto.set_harmonic(t.harmonic);
  proto.set_sine(t.sine);
  proto.set_period_s(t.period);
  if (t.kind == estimator::BasisKind::kExponentialDecay) proto.set_time_constant_s(t.time_constant);
  if (t.kind == estimator::BasisKind::kChannel) {
    proto.set_channel(t.channel);
    proto.set_channel_form(std::string(estimator::ChannelFormName(t.form)));
    proto.set_reference_value(t.reference);
    if (t.form != estimator::ChannelForm::kValue) proto.set_time_constant_s(t.time_constant);
  }
  *proto.mutable_epoch() = TimeToProto(t.epoch);
  const double to_json = estimator::BasisValueToJson(t.kind);
  proto.set_value_deg_h(Tidy(t.value * to_json));
  proto.set_sigma_deg_h(Tidy(t.sigma * to_json));
  return proto;
}

// ---------------------------------------------------------------------------------------------
// Drift model.

namespace {

// The GyroDriftModel field of a term: the one whose JSON name is the descriptor's key (looked up
// once per entry of kFixedTerms: a history export maps every snapshot); nullptr when none is.
const google::protobuf::FieldDescriptor* DriftModelField(
    const estimator::FixedTermDescriptor& term) {
  auto find = [](const estimator::FixedTermDescriptor& t) {
    return esg::v1::GyroDriftModel::descriptor()->FindFieldByCamelcaseName(
        std::string(t.json_key));
  };
  using Fields = std::array<const google::protobuf::FieldDescriptor*, estimator::kNumDriftCoefficients>;
  static const Fields* const fields = [&find] {
    auto* f = new Fields;
    for (int i = 0; i < estimator::kNumDriftCoefficients; ++i) (*f)[i] = find(estimator::kFixedTerms[i]);
    return f;
  }();
  const int i = term.theta_index;
  if (i >= 0 && i < estimator::kNumDriftCoefficients &&
      estimator::kFixedTerms[i].json_key == term.json_key) {
    return (*fields)[i];
  }
  return find(term);
}

// Number of entries of the term's JSON key (1 for a number, the vector's length otherwise).
int EntriesOfKey(absl::string_view json_key) {
  int n = 0;
  for (const estimator::FixedTermDescriptor& t : estimator::kFixedTerms) n += t.json_key == json_key;
  return n;
}

// Whether the message gives the term by its field (a number other than 0, a vector not empty).
bool GivenByField(const esg::v1::GyroDriftModel& proto,
                  const estimator::FixedTermDescriptor& term) {
  const google::protobuf::FieldDescriptor* f = DriftModelField(term);
  if (f == nullptr) return false;
  const google::protobuf::Reflection* reflection = proto.GetReflection();
  return f->is_repeated() ? reflection->FieldSize(proto, f) != 0
                          : reflection->GetDouble(proto, f) != 0.0;
}

// The keyed entry of the term (GyroDriftModel.coefficients), or nullptr.
const esg::v1::DriftCoefficient* KeyedEntry(const esg::v1::GyroDriftModel& proto,
                                            const estimator::FixedTermDescriptor& term) {
  for (const esg::v1::DriftCoefficient& c : proto.coefficients()) {
    if (absl::string_view(c.term()) == term.storage_key) return &c;
  }
  return nullptr;
}

// Checks the length of every vector key of a GyroDriftModel: empty (zero) or complete. The keys
// in table order, so the first wrong one is named. Then the keyed coefficients, in their order:
// each names a term of the table (estimator/model_terms.h storage_key), at most once, and one
// not also given by its field.
absl::Status CheckDriftModel(const esg::v1::GyroDriftModel& proto, absl::string_view field) {
  const google::protobuf::Reflection* reflection = proto.GetReflection();
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    if (term.component != 0) continue;  // once per vector key, at its first entry
    const google::protobuf::FieldDescriptor* f = DriftModelField(term);
    if (f == nullptr || !f->is_repeated()) continue;
    const int size = reflection->FieldSize(proto, f);
    const int expected = EntriesOfKey(term.json_key);
    if (size != 0 && size != expected) {
      return FieldError(absl::StrCat(field, ".", term.json_key),
                        absl::StrFormat("expected %d values, got %d", expected, size));
    }
  }
  std::array<bool, estimator::kNumDriftCoefficients> keyed{};
  for (int i = 0; i < proto.coefficients_size(); ++i) {
    const std::string& key = proto.coefficients(i).term();
    const estimator::FixedTermDescriptor* term = nullptr;
    for (const estimator::FixedTermDescriptor& t : estimator::kFixedTerms) {
      if (absl::string_view(key) == t.storage_key) term = &t;
    }
    const std::string at = absl::StrCat(field, ".coefficients[", i, "].term");
    if (term == nullptr) {
      std::string known;
      for (const estimator::FixedTermDescriptor& t : estimator::kFixedTerms) {
        absl::StrAppend(&known, known.empty() ? "" : ", ", t.storage_key);
      }
      return FieldError(at, absl::StrFormat("unknown term \"%s\" (terms: %s)",
                                            absl::CHexEscape(key), known));
    }
    if (keyed[term->theta_index]) {
      return FieldError(at, absl::StrFormat("term \"%s\" is given twice", key));
    }
    keyed[term->theta_index] = true;
    if (GivenByField(proto, *term)) {
      return FieldError(at, absl::StrFormat("term \"%s\" is also given by %s.%s; give it once",
                                            key, field, term->json_key));
    }
  }
  return absl::OkStatus();
}

}  // namespace

double DriftModelTermDegH(const esg::v1::GyroDriftModel& model,
                          const estimator::FixedTermDescriptor& term) {
  if (const esg::v1::DriftCoefficient* keyed = KeyedEntry(model, term)) return keyed->value_deg_h();
  const google::protobuf::FieldDescriptor* f = DriftModelField(term);
  if (f == nullptr) return 0.0;
  const google::protobuf::Reflection* reflection = model.GetReflection();
  if (!f->is_repeated()) return reflection->GetDouble(model, f);
  if (term.component >= reflection->FieldSize(model, f)) return 0.0;
  return reflection->GetRepeatedDouble(model, f, term.component);
}

void SetDriftModelTermDegH(const estimator::FixedTermDescriptor& term, double deg_h,
                           esg::v1::GyroDriftModel* model) {
  // Coefficients the message gives by their deprecated fields are keyed first, so that no term
  // is given both ways.
  bool by_field = false;
  for (const estimator::FixedTermDescriptor& t : estimator::kFixedTerms) {
    by_field |= GivenByField(*model, t);
  }
  if (by_field) {
    std::array<double, estimator::kNumDriftCoefficients> deg_h_of{};
    for (const estimator::FixedTermDescriptor& t : estimator::kFixedTerms) {
      deg_h_of[t.theta_index] = DriftModelTermDegH(*model, t);
    }
    const google::protobuf::Reflection* reflection = model->GetReflection();
    for (const estimator::FixedTermDescriptor& t : estimator::kFixedTerms) {
      if (!GivenByField(*model, t) || KeyedEntry(*model, t) != nullptr) continue;
      esg::v1::DriftCoefficient* c = model->add_coefficients();
      c->set_term(std::string(t.storage_key));
      c->set_value_deg_h(deg_h_of[t.theta_index]);
    }
    for (const estimator::FixedTermDescriptor& t : estimator::kFixedTerms) {
      if (const google::protobuf::FieldDescriptor* f = DriftModelField(t)) {
        reflection->ClearField(model, f);
      }
    }
  }
  for (esg::v1::DriftCoefficient& c : *model->mutable_coefficients()) {
    if (absl::string_view(c.term()) == term.storage_key) {
      c.set_value_deg_h(deg_h);
      return;
    }
  }
  esg::v1::DriftCoefficient* c = model->add_coefficients();
  c->set_term(std::string(term.storage_key));
  c->set_value_deg_h(deg_h);
}

absl::StatusOr<estimator::DriftCoefficients> DriftModelFromProto(const esg::v1::GyroDriftModel& proto,
                                                                 std::string_view field_name) {
  RETURN_IF_ERROR(CheckDriftModel(proto, AbslView(field_name)));
  estimator::DriftVector theta;
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    theta[term.theta_index] = estimator::DegPerHourToRadPerSec(DriftModelTermDegH(proto, term));
  }
  return estimator::DriftCoefficients::FromVector(theta);
}

namespace {

// Where the message gave a coefficient, as a message names it: "<field>.coefficients[2].valueDegH"
// when keyed (GyroDriftModel.coefficients), else its deprecated field "<field>.c1DegH[2]" (also
// for a term given by neither, which reads as 0).
std::string DriftTermPath(const esg::v1::GyroDriftModel& proto,
                          const estimator::FixedTermDescriptor& term, absl::string_view field) {
  for (int i = 0; i < proto.coefficients_size(); ++i) {
    if (absl::string_view(proto.coefficients(i).term()) == term.storage_key) {
      return absl::StrCat(field, ".coefficients[", i, "].valueDegH");
    }
  }
  return absl::StrCat(field, ".", estimator::FixedTermJsonName(term));
}

// SigmaKeptPositive for every coefficient of a modelSigma.
absl::Status DriftSigmasKeptPositive(const esg::v1::GyroDriftModel& proto,
                                     const estimator::DriftCoefficients& c,
                                     absl::string_view field) {
  const estimator::DriftVector theta = c.AsVector();
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    RETURN_IF_ERROR(SigmaKeptPositive(DriftModelTermDegH(proto, term), theta[term.theta_index],
                                      DriftTermPath(proto, term, field)));
  }
  return absl::OkStatus();
}

// The paths the configuration wrote its keyed coefficients at, by the field path ValidateConfig
// names a coefficient with ("gyros[1].model.c1DegH[2]" -> "gyros[1].model.coefficients[0].
// valueDegH").
using KeyedPaths = std::vector<std::pair<std::string, std::string>>;

void AddKeyedPaths(const esg::v1::GyroDriftModel& proto, absl::string_view field,
                   KeyedPaths* paths) {
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    if (KeyedEntry(proto, term) == nullptr) continue;
    paths->emplace_back(absl::StrCat(field, ".", estimator::FixedTermJsonName(term)),
                        DriftTermPath(proto, term, field));
  }
}

// ValidateConfig's refusal ("<field path>: <reason>") naming a coefficient by its field, as the
// user wrote it: the keyed path when it was given keyed, so that the message points at the line
// of the file (or the entry of the request) to correct.
absl::Status AtPathWritten(const absl::Status& status, const KeyedPaths& paths) {
  for (const auto& [field_path, keyed_path] : paths) {
    const std::string prefix = absl::StrCat(field_path, ": ");
    if (absl::StartsWith(status.message(), prefix)) {
      return absl::Status(status.code(),
                          absl::StrCat(keyed_path, ": ", status.message().substr(prefix.size())));
    }
  }
  return status;
}

}  // namespace

esg::v1::GyroDriftModel DriftModelToProto(const estimator::DriftCoefficients& coefficients) {
  esg::v1::GyroDriftModel proto;
  const estimator::DriftVector theta = coefficients.AsVector();
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    SetDriftModelTermDegH(term, TidyDegPerHour(theta[term.theta_index]), &proto);
  }
  return proto;
}

// ---------------------------------------------------------------------------------------------
// Configuration.

absl::StatusOr<estimator::SpacecraftConfig> ConfigFromProto(const esg::v1::SpacecraftConfig& proto) {
  using estimator::ArcsecToRad;
  estimator::SpacecraftConfig config;
  config.spacecraft_id = proto.spacecraft_id();
  KeyedPaths keyed_paths;
  for (int i = 0; i < proto.gyros_size(); ++i) {
    const esg::v1::GyroConfig& g = proto.gyros(i);
    const std::string prefix = absl::StrFormat("gyros[%d]", i);
    estimator::GyroConfig gyro;
    gyro.id = g.id();
    if (g.case_to_body_size() != 9) {
      return FieldError(absl::StrCat(prefix, ".caseToBody"),
                        absl::StrFormat("expected 9 values (C_b_k row-major), got %d",
                                        g.case_to_body_size()));
    }
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) gyro.C_b_k(r, c) = g.case_to_body(3 * r + c);
    }
    ASSIGN_OR_RETURN(gyro.model, DriftModelFromProto(g.model(), absl::StrCat(prefix, ".model")));
    ASSIGN_OR_RETURN(gyro.model_sigma,
                     DriftModelFromProto(g.model_sigma(), absl::StrCat(prefix, ".modelSigma")));
    RETURN_IF_ERROR(DriftSigmasKeptPositive(g.model_sigma(), gyro.model_sigma,
                                            absl::StrCat(prefix, ".modelSigma")));
    AddKeyedPaths(g.model(), absl::StrCat(prefix, ".model"), &keyed_paths);
    AddKeyedPaths(g.model_sigma(), absl::StrCat(prefix, ".modelSigma"), &keyed_paths);
    gyro.misalignment_sigma = ArcsecToRad(g.misalignment_sigma_arcsec());
    RETURN_IF_ERROR(SigmaKeptPositive(g.misalignment_sigma_arcsec(), gyro.misalignment_sigma,
                                      absl::StrCat(prefix, ".misalignmentSigmaArcsec")));
    for (int k = 0; k < g.basis_terms_size(); ++k) {
      ASSIGN_OR_RETURN(estimator::BasisTerm term,
                       BasisTermFromProto(g.basis_terms(k),
                                          absl::StrFormat("%s.basisTerms[%d]", prefix, k)));
      gyro.basis_terms.push_back(std::move(term));
    }
    if (!g.readout_distortion().empty()) {
      const std::string field = absl::StrCat(prefix, ".readoutDistortion");
      if (g.readout_distortion_size() != 9) {
        return FieldError(field, absl::StrFormat("expected 9 values (D row-major) or none, got %d",
                                                 g.readout_distortion_size()));
      }
      RETURN_IF_ERROR(AllFinite(g.readout_distortion(), field));
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) gyro.readout_distortion(r, c) = g.readout_distortion(3 * r + c);
      }
    }
    config.gyros.push_back(std::move(gyro));
  }
  ASSIGN_OR_RETURN(config.working_pair, Pair(proto.working_pair(), "workingPair"));
  ASSIGN_OR_RETURN(config.reserve_pair, Pair(proto.reserve_pair(), "reservePair"));
  ASSIGN_OR_RETURN(const Eigen::Vector3d noise_arcsec,
                   OptionalVector3(proto.star_tracker().noise_arcsec(), "starTracker.noiseArcsec"));
  config.star_tracker.noise = noise_arcsec.unaryExpr(&ArcsecToRad);
  config.star_tracker.latency = proto.star_tracker().latency_s();
  config.star_tracker.latency_sigma = proto.star_tracker().latency_sigma_s();
  config.readout_noise = ArcsecToRad(proto.readout_noise_arcsec());
  config.random_walk = estimator::DegPerHourSqrtHourToSi(proto.random_walk_deg_h_sqrt_h());

  // Zero (absent) means the documented default, taken from the estimator's value types.
  const estimator::SuspensionConfig default_suspension;
  const esg::v1::SuspensionConfig& s = proto.suspension();
  config.suspension.amplifier_gain =
      s.amplifier_gain() != 0.0 ? s.amplifier_gain() : default_suspension.amplifier_gain;
  config.suspension.reference_voltage = s.reference_voltage_v() != 0.0
                                            ? s.reference_voltage_v()
                                            : default_suspension.reference_voltage;
  config.suspension.gap =
      s.gap_um() != 0.0 ? s.gap_um() * estimator::kMetresPerUm : default_suspension.gap;

  const estimator::FilterConfig default_filter;
  const esg::v1::FilterConfig& f = proto.filter();
  config.filter.integration_rate_hz = f.integration_rate_hz() != 0.0
                                          ? f.integration_rate_hz()
                                          : default_filter.integration_rate_hz;
  config.filter.measurement_step =
      f.measurement_step_s() != 0.0 ? f.measurement_step_s() : default_filter.measurement_step;
  config.filter.innovation_kd =
      f.innovation_kd() != 0.0 ? f.innovation_kd() : default_filter.innovation_kd;
  config.filter.fault_threshold = ArcsecToRad(f.fault_threshold_arcsec());  // 0 = derived
  config.filter.drift_change_limit = f.drift_change_limit_deg_h() != 0.0
                                         ? estimator::DegPerHourToRadPerSec(f.drift_change_limit_deg_h())
                                         : default_filter.drift_change_limit;

  for (int i = 0; i < proto.channels_size(); ++i) {
    const esg::v1::ChannelConfig& c = proto.channels(i);
    estimator::ChannelConfig channel;
    channel.name = c.name();
    channel.unit = c.unit();
    channel.valid_min = c.valid_min();
    channel.valid_max = c.valid_max();
    // Checked here, before absl::Seconds, which has no NaN; the range is ValidateConfig's.
    if (!std::isfinite(c.max_age_s())) {
      return FieldError(absl::StrCat("channels[", i, "].maxAgeS"),
                        absl::StrFormat("%g is not finite", c.max_age_s()));
    }
    channel.max_age = absl::Seconds(c.max_age_s());
    config.channels.push_back(std::move(channel));
  }

  if (absl::Status s = estimator::ValidateConfig(config); !s.ok()) {
    return AtPathWritten(s, keyed_paths);
  }
  return config;
}

esg::v1::SpacecraftConfig ConfigToProto(const estimator::SpacecraftConfig& config) {
  esg::v1::SpacecraftConfig proto;
  proto.set_spacecraft_id(config.spacecraft_id);
  for (const estimator::GyroConfig& gyro : config.gyros) {
    esg::v1::GyroConfig* g = proto.add_gyros();
    g->set_id(gyro.id);
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) g->add_case_to_body(gyro.C_b_k(r, c));  // exact, no unit
    }
    *g->mutable_model() = DriftModelToProto(gyro.model);
    *g->mutable_model_sigma() = DriftModelToProto(gyro.model_sigma);
    g->set_misalignment_sigma_arcsec(TidyArcsec(gyro.misalignment_sigma));
    for (const estimator::BasisTerm& t : gyro.basis_terms) *g->add_basis_terms() = BasisTermToProto(t);
    if (!gyro.readout_distortion.isZero(0.0)) {
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) g->add_readout_distortion(gyro.readout_distortion(r, c));
      }
    }
  }
  for (int id : config.working_pair) proto.add_working_pair(id);
  for (int id : config.reserve_pair) proto.add_reserve_pair(id);
  SetVector3(config.star_tracker.noise.unaryExpr(&TidyArcsec),
             proto.mutable_star_tracker()->mutable_noise_arcsec());
  proto.mutable_star_tracker()->set_latency_s(config.star_tracker.latency);
  proto.mutable_star_tracker()->set_latency_sigma_s(config.star_tracker.latency_sigma);
  proto.set_readout_noise_arcsec(TidyArcsec(config.readout_noise));
  proto.set_random_walk_deg_h_sqrt_h(Tidy(estimator::SiToDegPerHourSqrtHour(config.random_walk)));
  esg::v1::SuspensionConfig* s = proto.mutable_suspension();
  s->set_amplifier_gain(config.suspension.amplifier_gain);
  s->set_reference_voltage_v(config.suspension.reference_voltage);
  s->set_gap_um(Tidy(config.suspension.gap / estimator::kMetresPerUm));
  esg::v1::FilterConfig* f = proto.mutable_filter();
  f->set_integration_rate_hz(config.filter.integration_rate_hz);
  f->set_measurement_step_s(config.filter.measurement_step);
  f->set_innovation_kd(config.filter.innovation_kd);
  f->set_fault_threshold_arcsec(TidyArcsec(config.filter.fault_threshold));
  f->set_drift_change_limit_deg_h(TidyDegPerHour(config.filter.drift_change_limit));
  for (const estimator::ChannelConfig& channel : config.channels) {
    esg::v1::ChannelConfig* c = proto.add_channels();
    c->set_name(channel.name);
    c->set_unit(channel.unit);
    c->set_valid_min(channel.valid_min);
    c->set_valid_max(channel.valid_max);
    c->set_max_age_s(absl::ToDoubleSeconds(channel.max_age));
  }
  return proto;
}

namespace {

// What always_print_primitive_fields prints for each deprecated field of GyroDriftModel left empty
// ("<jsonName>":0, or "<jsonName>":[], followed by the comma before the keyed coefficients, its
// last field), each mapped to nothing.
const std::vector<std::pair<std::string, std::string>>& EmptyDeprecatedDriftFields() {
  static const auto* const cuts = [] {
    auto* c = new std::vector<std::pair<std::string, std::string>>;
    const google::protobuf::Descriptor* d = esg::v1::GyroDriftModel::descriptor();
    for (int i = 0; i < d->field_count(); ++i) {
      const google::protobuf::FieldDescriptor* f = d->field(i);
      if (!f->options().deprecated()) continue;
      c->emplace_back(absl::StrCat("\"", f->json_name(), "\":", f->is_repeated() ? "[]" : "0", ","),
                      "");
    }
    return c;
  }();
  return *cuts;
}

}  // namespace

absl::StatusOr<estimator::SpacecraftConfig> ParseConfigJson(std::string_view json) {
  // protobuf's parser keeps one value of a repeated key and flattens nested arrays.
  if (absl::Status strict = CheckStrictJson(json); !strict.ok()) {
    if (absl::StartsWith(strict.message(), "not valid JSON")) {
      return absl::InvalidArgumentError(absl::StrCat("config JSON: ", strict.message()));
    }
    return strict;
  }
  esg::v1::SpacecraftConfig proto;
  google::protobuf::util::JsonParseOptions options;
  options.ignore_unknown_fields = false;
  const auto status = google::protobuf::util::JsonStringToMessage(
      google::protobuf::StringPiece(json.data(), json.size()), &proto, options);
  if (!status.ok()) {
    return absl::InvalidArgumentError(
        JsonErrorMessage(std::string(status.message().data(), status.message().size())));
  }
  return ConfigFromProto(proto);
}

std::string ConfigToJson(const estimator::SpacecraftConfig& config) {
  google::protobuf::util::JsonPrintOptions options;
  options.add_whitespace = false;  // JsonPrettyPrinter lays it out
  options.always_print_primitive_fields = true;
  options.preserve_proto_field_names = false;
  std::string json;
  // Printing a valid message cannot fail; an empty string signals the impossible case.
  if (!google::protobuf::util::MessageToJsonString(ConfigToProto(config), &json, options).ok()) {
    return std::string();
  }
  // A drift model's deprecated fields (the form of the release before its keyed coefficients)
  // are never written: ConfigToProto leaves them empty, and their printed defaults are cut.
  json = absl::StrReplaceAll(json, EmptyDeprecatedDriftFields());
  // A configuration without channels prints as it did before the field existed: the service
  // compares the stored text to tell a changed configuration from the same one sent again
  // (storage/config_store.cc, server/estimation_core.cc), so an empty "channels" must not make an
  // unchanged configuration new. The field is the message's last, printed last.
  constexpr absl::string_view kNoChannels = ",\"channels\":[]}";
  if (config.channels.empty() && absl::EndsWith(json, kNoChannels)) {
    json.replace(json.size() - kNoChannels.size(), kNoChannels.size(), "}");
  }
  return JsonPrettyPrinter(json).Print();
}

std::string BasisTermToJson(const estimator::BasisTerm& term) {
  google::protobuf::util::JsonPrintOptions options;
  options.add_whitespace = false;
  options.always_print_primitive_fields = true;
  std::string json;
  if (!google::protobuf::util::MessageToJsonString(BasisTermToProto(term), &json, options).ok()) {
    return std::string();
  }
  return json;
}

absl::StatusOr<estimator::SpacecraftConfig> ReadConfigFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return absl::NotFoundError(
        absl::StrCat("config file ", path, ": cannot open: ", std::strerror(errno)));
  }
  std::ostringstream content;
  content << in.rdbuf();
  if (in.bad()) return absl::UnavailableError(absl::StrCat("config file ", path, ": read failed"));
  absl::StatusOr<estimator::SpacecraftConfig> config = ParseConfigJson(content.str());
  if (!config.ok()) {
    return absl::Status(config.status().code(), absl::StrCat(path, ": ", config.status().message()));
  }
  return config;
}

absl::Status WriteConfigFile(const std::string& path, const estimator::SpacecraftConfig& config) {
  RETURN_IF_ERROR(estimator::ValidateConfig(config));
  const std::string json = ConfigToJson(config);
  if (json.empty()) return absl::InternalError("config: JSON printing failed");
  const std::string tmp_path = path + ".tmp";
  {
    std::ofstream out(tmp_path, std::ios::binary | std::ios::trunc);
    if (!out) {
      return absl::UnavailableError(
          absl::StrCat("config file ", tmp_path, ": cannot create: ", std::strerror(errno)));
    }
    out << json;
    out.flush();
    if (!out) {
      return absl::UnavailableError(absl::StrCat("config file ", tmp_path, ": write failed"));
    }
  }
  if (std::rename(tmp_path.c_str(), path.c_str()) != 0) {
    const int err = errno;
    std::remove(tmp_path.c_str());
    return absl::UnavailableError(
        absl::StrCat("config file ", path, ": cannot rename: ", std::strerror(err)));
  }
  return absl::OkStatus();
}

// ---------------------------------------------------------------------------------------------
// Telemetry frames.

absl::StatusOr<estimator::TelemetryFrame> FrameFromProto(const esg::v1::TelemetryFrame& proto) {
  estimator::TelemetryFrame frame;
  // First, so that no other message of this frame carries a hostile id further.
  RETURN_IF_ERROR(estimator::ValidateIdentifier(proto.spacecraft_id(), "spacecraft_id"));
  if (!proto.has_time()) return FieldError("time", "missing");
  absl::StatusOr<absl::Time> time = TimeFromProto(proto.time());
  if (!time.ok()) return FieldError("time", time.status().message());
  frame.time = *time;

  for (int i = 0; i < proto.gyros_size(); ++i) {
    const esg::v1::GyroReading& g = proto.gyros(i);
    const std::string prefix = absl::StrFormat("gyros[%d]", i);
    const int id = g.gyro_id();
    if (id < 1 || id > estimator::kMaxGyros) {
      return FieldError(absl::StrCat(prefix, ".gyro_id"),
                        absl::StrFormat("%d is outside 1..%d", id, estimator::kMaxGyros));
    }
    std::optional<estimator::GyroReading>& slot = frame.gyros[id - 1];
    if (slot.has_value()) {
      return FieldError(absl::StrCat(prefix, ".gyro_id"),
                        absl::StrFormat("gyro %d appears twice", id));
    }
    estimator::GyroReading reading;
    ASSIGN_OR_RETURN(reading.h_k, UnitVector<3>(g.h_k(), absl::StrCat(prefix, ".h_k")));
    if (!g.u_k_mv().empty()) {
      const std::string field = absl::StrCat(prefix, ".u_k_mv");
      if (g.u_k_mv_size() != 3) {
        return FieldError(field, absl::StrFormat("expected 3 values or none, got %d",
                                                 g.u_k_mv_size()));
      }
      RETURN_IF_ERROR(AllFinite(g.u_k_mv(), field));
      for (int axis = 0; axis < 3; ++axis) {
        if (!(std::abs(g.u_k_mv(axis)) <= kMaxSuspensionOffsetMv)) {
          return FieldError(
              absl::StrFormat("%s[%d]", field, axis),
              absl::StrFormat("%g mV is beyond +-%g mV: an offset voltage cannot exceed the "
                              "largest suspension reference voltage a configuration may have "
                              "(suspension.referenceVoltageV, docs/formats.md)",
                              g.u_k_mv(axis), kMaxSuspensionOffsetMv));
        }
      }
      reading.u_k_mv = Eigen::Vector3d(g.u_k_mv(0), g.u_k_mv(1), g.u_k_mv(2));
    }
    slot = std::move(reading);
  }

  if (proto.has_star_tracker()) {
    const esg::v1::StarTrackerReading& st = proto.star_tracker();
    estimator::StarTrackerReading reading;
    reading.valid = st.valid();
    if (st.valid()) {
      ASSIGN_OR_RETURN(const Eigen::Vector4d q, UnitVector<4>(st.q_in_b(), "star_tracker.q_in_b"));
      reading.q_in_b = estimator::QuaternionFromScalarFirst({q[0], q[1], q[2], q[3]});
    } else if (!st.q_in_b().empty()) {
      // Not carried, but a malformed value still points at a broken producer.
      if (st.q_in_b_size() != 4) {
        return FieldError("star_tracker.q_in_b",
                          absl::StrFormat("expected 4 values or none, got %d", st.q_in_b_size()));
      }
      RETURN_IF_ERROR(AllFinite(st.q_in_b(), "star_tracker.q_in_b"));
    }
    frame.star_tracker = reading;
  }
  // Whether each channel is declared, and within its range, is the caller's (it knows the
  // configuration: estimator::CheckDeclaredChannels).
  if (proto.channels_size() > estimator::kMaxChannels) {
    return FieldError("channels", absl::StrFormat("%d channels, at most %d in a frame",
                                                  proto.channels_size(), estimator::kMaxChannels));
  }
  for (const auto& [name, value] : proto.channels()) frame.channels.Set(name, value);
  RETURN_IF_ERROR(estimator::ValidateFrameChannels(frame.channels));
  return frame;
}

esg::v1::TelemetryFrame FrameToProto(const estimator::TelemetryFrame& frame,
                                     std::string spacecraft_id, int64_t sequence) {
  esg::v1::TelemetryFrame proto;
  proto.set_spacecraft_id(std::move(spacecraft_id));
  proto.set_sequence(sequence);
  *proto.mutable_time() = TimeToProto(frame.time);
  for (int i = 0; i < estimator::kMaxGyros; ++i) {
    const std::optional<estimator::GyroReading>& reading = frame.gyros[i];
    if (!reading.has_value()) continue;
    esg::v1::GyroReading* g = proto.add_gyros();
    g->set_gyro_id(i + 1);
    SetVector3(reading->h_k, g->mutable_h_k());
    if (reading->u_k_mv.has_value()) SetVector3(*reading->u_k_mv, g->mutable_u_k_mv());
  }
  if (frame.star_tracker.has_value()) {
    esg::v1::StarTrackerReading* st = proto.mutable_star_tracker();
    st->set_valid(frame.star_tracker->valid);
    if (frame.star_tracker->valid) {
      for (double v : estimator::ToScalarFirst(frame.star_tracker->q_in_b)) st->add_q_in_b(v);
    }
  }
  for (const estimator::ChannelValue& c : frame.channels) {
    (*proto.mutable_channels())[c.name] = c.value;
  }
  return proto;
}

// ---------------------------------------------------------------------------------------------
// Time.

absl::StatusOr<absl::Time> TimeFromProto(const google::protobuf::Timestamp& timestamp) {
  if (timestamp.seconds() < kMinTimestampSeconds || timestamp.seconds() > kMaxTimestampSeconds) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "seconds %d is outside 0001-01-01..9999-12-31", timestamp.seconds()));
  }
  if (timestamp.nanos() < 0 || timestamp.nanos() > 999999999) {
    return absl::InvalidArgumentError(
        absl::StrFormat("nanos %d is outside 0..999999999", timestamp.nanos()));
  }
  return absl::FromUnixSeconds(timestamp.seconds()) + absl::Nanoseconds(timestamp.nanos());
}

google::protobuf::Timestamp TimeToProto(absl::Time time) {
  google::protobuf::Timestamp timestamp;
  const absl::Time min_time = absl::FromUnixSeconds(kMinTimestampSeconds);
  const absl::Time max_time =
      absl::FromUnixSeconds(kMaxTimestampSeconds) + absl::Nanoseconds(999999999);
  if (time < min_time) time = min_time;
  if (time > max_time) time = max_time;
  // Floor division: nanos stays in 0..999999999 for instants before 1970 too.
  const int64_t seconds = absl::ToUnixSeconds(time);
  const absl::Duration rest = time - absl::FromUnixSeconds(seconds);
  timestamp.set_seconds(seconds);
  timestamp.set_nanos(static_cast<int32_t>(absl::ToInt64Nanoseconds(rest)));
  return timestamp;
}

}  // namespace esg::proto_convert
