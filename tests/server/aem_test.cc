// CCSDS AEM writer and reader/validator (formats/aem.h, docs/formats.md "Attitude product"): the
// writer's output passes the reader and round-trips q_in_b; the reader rejects files that break
// the standard's rules.
#include "formats/aem.h"

#include <string>

#include "absl/strings/str_replace.h"
#include "absl/strings/str_split.h"
#include "estimator/rotation.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/quaternion_matchers.h"
#include "tests/testing/status_matchers.h"

namespace esg::storage {
namespace {

using ::esg::testing::IsNearQuaternion;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::HasSubstr;

const absl::Time kStart = absl::FromUnixSeconds(1551398400);  // 2019-03-01T00:00:00Z

std::vector<AemSample> Samples(int n) {
  std::vector<AemSample> samples;
  for (int i = 0; i < n; ++i) {
    // Attitudes with both signs of the scalar part, to exercise canonicalisation.
    const Eigen::Vector3d v(0.3 + 0.1 * i, -0.2, 2.5 + 0.4 * i);
    samples.push_back({kStart + absl::Seconds(60 * i), estimator::ExpQuaternion(v)});
  }
  return samples;
}

std::string ValidText() {
  AemHeader header;
  header.object_name = "RDK-1";
  header.object_id = "2019-001A";
  header.creation_date = kStart;
  header.comments = {"test"};
  auto text = WriteAem(header, Samples(5));
  EXPECT_THAT(text, IsOk());
  return *text;
}

TEST(Aem, WriterOutputPassesReaderAndRoundTripsAttitude) {
  const std::string text = ValidText();
  auto parsed = ParseAem(text);
  ASSERT_THAT(parsed, IsOk());
  EXPECT_EQ(parsed->version, "2.0");
  EXPECT_EQ(parsed->header.at("ORIGINATOR"), "ESG");
  ASSERT_EQ(parsed->segments.size(), 1u);
  const AemSegment& seg = parsed->segments[0];
  EXPECT_EQ(seg.metadata.at("REF_FRAME_A"), "EME2000");
  EXPECT_EQ(seg.metadata.at("REF_FRAME_B"), "SC_BODY_1");
  EXPECT_EQ(seg.metadata.at("TIME_SYSTEM"), "UTC");
  EXPECT_EQ(seg.metadata.at("ATTITUDE_TYPE"), "QUATERNION");
  EXPECT_EQ(seg.start_time, kStart);
  EXPECT_EQ(seg.stop_time, kStart + absl::Seconds(240));
  const std::vector<AemSample> expected = Samples(5);
  ASSERT_EQ(seg.samples.size(), expected.size());
  for (size_t i = 0; i < expected.size(); ++i) {
    EXPECT_EQ(seg.samples[i].epoch, expected[i].epoch);
    EXPECT_THAT(seg.samples[i].q_in_b, IsNearQuaternion(expected[i].q_in_b, 1e-12));
    EXPECT_GE(seg.samples[i].q_in_b.w(), 0.0);  // QC canonical
  }
}

TEST(Aem, ScalarIsWrittenLastAndCanonical) {
  AemHeader header;
  header.object_name = header.object_id = "X";
  header.creation_date = kStart;
  // q_in_b = (q0, q1, q2, q3) = (-0.8, 0.2, -0.4, 0.4) / |.|: written as Q1 Q2 Q3 QC with QC >= 0.
  const Eigen::Quaterniond q = Eigen::Quaterniond(-0.8, 0.2, -0.4, 0.4).normalized();
  auto text = WriteAem(header, {{kStart, q}});
  ASSERT_THAT(text, IsOk());
  const size_t begin = text->find("DATA_START\n") + 11;
  const std::vector<std::string> fields =
      absl::StrSplit(text->substr(begin, text->find('\n', begin) - begin), ' ');
  ASSERT_EQ(fields.size(), 5u);
  EXPECT_EQ(fields[0], "2019-03-01T00:00:00.000000");
  const double expected[4] = {-q.x(), -q.y(), -q.z(), -q.w()};
  for (int i = 0; i < 4; ++i) EXPECT_NEAR(std::stod(fields[i + 1]), expected[i], 1e-15);
}

TEST(Aem, WriterRejectsBadInput) {
  AemHeader header;
  header.object_name = header.object_id = "X";
  std::vector<AemSample> unordered = Samples(3);
  std::swap(unordered[1], unordered[2]);
  EXPECT_THAT(WriteAem(header, unordered),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("samples[2].epoch")));
  EXPECT_THAT(WriteAem(header, {}), StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("samples")));
  header.object_id.clear();
  EXPECT_THAT(WriteAem(header, Samples(2)),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("OBJECT_ID")));
}

struct BrokenCase {
  const char* name;
  std::string from;
  std::string to;
  const char* message;
};

TEST(Aem, ReaderRejectsBrokenFiles) {
  const std::string valid = ValidText();
  const BrokenCase cases[] = {
      {"missing OBJECT_ID", "OBJECT_ID = 2019-001A\n", "", "OBJECT_ID"},
      {"missing ORIGINATOR", "ORIGINATOR = ESG\n", "", "ORIGINATOR"},
      {"missing version", "CCSDS_AEM_VERS = 2.0\n", "", "CCSDS_AEM_VERS"},
      {"v2 with QUATERNION_TYPE", "ATTITUDE_TYPE = QUATERNION\n",
       "ATTITUDE_TYPE = QUATERNION\nQUATERNION_TYPE = LAST\n", "QUATERNION_TYPE"},
      {"two body frames", "REF_FRAME_A = EME2000", "REF_FRAME_A = SC_BODY_2", "REF_FRAME_A/REF_FRAME_B"},
      {"no body frame", "REF_FRAME_B = SC_BODY_1", "REF_FRAME_B = ICRF", "REF_FRAME_A/REF_FRAME_B"},
      {"unordered epochs", "2019-03-01T00:02:00.000000 ", "2019-02-28T23:59:00.000000 ", "epoch"},
      {"epoch after STOP_TIME", "STOP_TIME = 2019-03-01T00:04:00.000000",
       "STOP_TIME = 2019-03-01T00:03:00.000000", "outside START_TIME..STOP_TIME"},
      {"epoch before START_TIME", "START_TIME = 2019-03-01T00:00:00.000000",
       "START_TIME = 2019-03-01T00:00:30.000000", "outside START_TIME..STOP_TIME"},
      {"unknown keyword", "TIME_SYSTEM = UTC\n", "TIME_SYSTEM = UTC\nFOO = 1\n", "FOO"},
      {"unknown time system", "TIME_SYSTEM = UTC", "TIME_SYSTEM = XYZ", "TIME_SYSTEM"},
      {"no DATA_STOP", "DATA_STOP\n", "", "DATA_STOP"},
      {"repeated keyword", "OBJECT_NAME = RDK-1\n", "OBJECT_NAME = RDK-1\nOBJECT_NAME = B\n",
       "repeated"},
      {"non-unit quaternion", " 0.", " 1.", "norm"},
  };
  for (const BrokenCase& c : cases) {
    SCOPED_TRACE(c.name);
    ASSERT_THAT(valid, HasSubstr(c.from));
    const std::string broken = absl::StrReplaceAll(valid, {{c.from, c.to}});
    ASSERT_NE(broken, valid);
    EXPECT_THAT(ParseAem(broken), StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr(c.message)));
  }
}

TEST(Aem, ReaderAcceptsVersion1WithScalarFirst) {
  const std::string text =
      "CCSDS_AEM_VERS = 1.0\nCREATION_DATE = 2019-060T00:00:00\nORIGINATOR = X\n"
      "META_START\nOBJECT_NAME = A\nOBJECT_ID = A\nREF_FRAME_A = SC_BODY_1\nREF_FRAME_B = EME2000\n"
      "ATTITUDE_DIR = A2B\nTIME_SYSTEM = UTC\nSTART_TIME = 2019-03-01T00:00:00\n"
      "STOP_TIME = 2019-03-01T00:01:00\nATTITUDE_TYPE = QUATERNION\nQUATERNION_TYPE = FIRST\n"
      "META_STOP\nDATA_START\n2019-03-01T00:00:00Z 0.70710678118654757 0 0 0.70710678118654757\n"
      "DATA_STOP\n";
  auto parsed = ParseAem(text);
  ASSERT_THAT(parsed, IsOk());
  // Frame A is the body: the file's quaternion is q_b_in, read back as its conjugate q_in_b.
  const Eigen::Quaterniond q_b_in(std::sqrt(0.5), 0, 0, std::sqrt(0.5));
  EXPECT_THAT(parsed->segments[0].samples[0].q_in_b, IsNearQuaternion(q_b_in.conjugate(), 1e-12));
  // Version 1 without ATTITUDE_DIR is rejected.
  EXPECT_THAT(ParseAem(absl::StrReplaceAll(text, {{"ATTITUDE_DIR = A2B\n", ""}})),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("ATTITUDE_DIR")));
}

TEST(Aem, CcsdsTimeFormats) {
  EXPECT_EQ(*ParseCcsdsTime("2019-03-01T00:00:01.5"), kStart + absl::Milliseconds(1500));
  EXPECT_EQ(*ParseCcsdsTime("2019-060T00:00:00Z"), kStart);
  EXPECT_THAT(ParseCcsdsTime("2019-02-30T00:00:00"), StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("date")));
  EXPECT_THAT(ParseCcsdsTime("yesterday"), StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("CCSDS")));
}

// Found by fuzz/fuzz_aem.cc (docs/fuzzing.md, finding 2): a run of digits in the seconds (or in
// another field read as digits, e.g. SC_BODY_<n>) overflowed an int before its length was
// checked (undefined behaviour, reported by UBSan). The fuzzer's input, then the fields alone.
TEST(Aem, LongDigitRunsAreRefusedWithoutOverflow) {
  const std::string fuzzer_input =
      "CCSDS_AEM_VERS = 2.0\nCREATION_DATE = 2019-03-01T00:00:0085304411261 -0.776050292830884 "
      "0.041254056559672\nDATA_STOP\n";
  EXPECT_THAT(ParseAem(fuzzer_input),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("CREATION_DATE")));
  EXPECT_THAT(ParseCcsdsTime("2019-03-01T00:00:0085304411261"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("seconds")));
  EXPECT_THAT(ParseCcsdsTime("99999999999-03-01T00:00:00"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("date")));
  const std::string body_frame =
      absl::StrReplaceAll(ValidText(), {{"SC_BODY_1", "SC_BODY_99999999999"}});
  EXPECT_THAT(ParseAem(body_frame),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("REF_FRAME_B")));
}

}  // namespace
}  // namespace esg::storage
