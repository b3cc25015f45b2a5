// CCSDS Attitude Ephemeris Message (AEM) in KVN, ADM version 2 (CCSDS 504.0-B-2), the attitude
// product of docs/formats.md: a writer for predicted q_in_b, and a reader/validator of the
// project's own that applies the standard's structural rules (no AEM reader can be installed here).
//
// Written form (one segment):
//   CCSDS_AEM_VERS = 2.0, CREATION_DATE, ORIGINATOR, META_START, OBJECT_NAME, OBJECT_ID,
//   REF_FRAME_A = EME2000, REF_FRAME_B = SC_BODY_1, TIME_SYSTEM = UTC, START_TIME, STOP_TIME,
//   ATTITUDE_TYPE = QUATERNION, META_STOP, DATA_START, one line `epoch Q1 Q2 Q3 QC` per sample,
//   DATA_STOP. Quaternion direction (ADM v2: always from frame A to frame B): the rotation that
//   turns the EME2000 axes onto the body axes, i.e. our q_in_b (whose matrix is C_in_b: body
//   coordinates to inertial); the vector part first and the scalar QC last, sign canonical
//   (QC >= 0). Epochs are CCSDS ASCII time code A, UTC, microsecond resolution, no `Z`.
#ifndef ESG_STORAGE_AEM_H_
#define ESG_STORAGE_AEM_H_

#include <map>
#include <string>
#include "absl/strings/string_view.h"
#include <vector>

#include "Eigen/Geometry"
#include "absl/status/statusor.h"
#include "absl/time/time.h"

namespace esg::storage {

struct AemHeader {
  std::string object_name;  // e.g. the spacecraft id
  std::string object_id;    // international designator or the spacecraft id
  std::string originator = "ESG";
  absl::Time creation_date;
  std::vector<std::string> comments;  // written as COMMENT lines in the metadata
};

struct AemSample {
  absl::Time epoch;
  Eigen::Quaterniond q_in_b;  // body -> inertial (EME2000 ~ J2000 axes), unit
};

// Writes a one-segment AEM with START_TIME/STOP_TIME = first/last epoch. InvalidArgument naming
// the field for an empty OBJECT_NAME/OBJECT_ID/ORIGINATOR, no samples, epochs not strictly
// increasing ("samples[3].epoch: ..."), or a non-finite or non-unit (1e-6) quaternion.
absl::StatusOr<std::string> WriteAem(const AemHeader& header, const std::vector<AemSample>& samples);

// A parsed, validated AEM.
struct AemSegment {
  std::map<std::string, std::string> metadata;  // keyword -> value (COMMENT excluded)
  absl::Time start_time;
  absl::Time stop_time;
  std::vector<AemSample> samples;  // quaternions as q_in_b (frame A = inertial, B = body)
};
struct AemFile {
  std::string version;                        // "1.0" or "2.0"
  std::map<std::string, std::string> header;  // keyword -> value (COMMENT excluded)
  std::vector<AemSegment> segments;
};

// Parses and validates an AEM in KVN. Rules applied (CCSDS 504.0-B-2 §4 and 504.0-B-1 for
// version 1.0): the first keyword is CCSDS_AEM_VERS (1.0 or 2.0); header keywords CREATION_DATE and
// ORIGINATOR required, no unknown header keyword; at least one segment of META_START ... META_STOP
// then DATA_START ... DATA_STOP; metadata requires OBJECT_NAME, OBJECT_ID, REF_FRAME_A,
// REF_FRAME_B, TIME_SYSTEM, START_TIME, STOP_TIME, ATTITUDE_TYPE, plus for version 1.0
// ATTITUDE_DIR (A2B/B2A) and, for quaternions, QUATERNION_TYPE (FIRST/LAST); version 2.0 forbids
// those two; no keyword repeated or unknown; exactly one of REF_FRAME_A/REF_FRAME_B is a
// spacecraft-body frame (SC_BODY_<n>); START_TIME <= STOP_TIME, USEABLE_START/STOP_TIME inside
// them; ATTITUDE_TYPE QUATERNION (the only type this reader decodes); data lines: an epoch and 4
// numbers, epochs strictly increasing and inside [START_TIME, STOP_TIME], quaternion norm 1 within
// 1e-6. Errors: InvalidArgument "line <n>: <keyword or field>: <reason>".
absl::StatusOr<AemFile> ParseAem(absl::string_view text);

// CCSDS ASCII time code A ("YYYY-MM-DDThh:mm:ss[.d...]") or B ("YYYY-DDDThh:mm:ss[.d...]"), an
// optional trailing `Z`, UTC. InvalidArgument otherwise.
absl::StatusOr<absl::Time> ParseCcsdsTime(absl::string_view text);
std::string FormatCcsdsTime(absl::Time time);

}  // namespace esg::storage

#endif  // ESG_STORAGE_AEM_H_
