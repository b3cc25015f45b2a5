// CCSDS Attitude Ephemeris Message (AEM) in KVN, ADM version 2 (CCSDS 504.0-B-2), the attitude
// product of docs/formats.md: a writer for predicted q_in_b, and a reader/validator of the
// project's own that applies the standard's structural rules (no AEM reader can be installed here).
//
// Written form (one segment per block):
//   CCSDS_AEM_VERS = 2.0, CREATION_DATE, ORIGINATOR, MESSAGE_ID (when given), then per block
//   META_START, its COMMENT lines, OBJECT_NAME, OBJECT_ID, REF_FRAME_A = EME2000,
//   REF_FRAME_B = SC_BODY_1, TIME_SYSTEM = UTC, START_TIME, STOP_TIME, ATTITUDE_TYPE =
//   QUATERNION, INTERPOLATION_METHOD / INTERPOLATION_DEGREE (when given), META_STOP,
//   DATA_START, the 1-sigma of every sample that has one as COMMENT lines at the start of the data
//   section (the only place ADM allows comments there), one per sample:
//     COMMENT SIGMA_ARCSEC <epoch> <sigma_x> <sigma_y> <sigma_z>
//   (1-sigma about the body axes x, y, z [arcsec]), then one line `epoch Q1 Q2 Q3 QC` per sample,
//   DATA_STOP. Quaternion direction (ADM v2: always from frame A to frame B): the rotation that
//   turns the EME2000 axes onto the body axes, i.e. our q_in_b (whose matrix is C_in_b: body
//   coordinates to inertial); the vector part first and the scalar QC last, sign canonical
//   (QC >= 0). Epochs are CCSDS ASCII time code A, UTC, microsecond resolution, no `Z`.
#ifndef ESG_FORMATS_AEM_H_
#define ESG_FORMATS_AEM_H_

#include <map>
#include <optional>
#include <string>
#include <vector>

#include "absl/strings/string_view.h"

#include "Eigen/Geometry"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "formats/ccsds_kvn.h"

namespace esg::storage {

struct AemHeader {
  std::string object_name;  // e.g. the spacecraft id
  std::string object_id;    // international designator or the spacecraft id
  std::string originator = "ESG";
  absl::Time creation_date;
  std::vector<std::string> comments;  // written as COMMENT lines in the metadata
  std::string message_id;             // MESSAGE_ID header keyword; omitted when empty
};

struct AemSample {
  absl::Time epoch;
  Eigen::Quaterniond q_in_b;  // body -> inertial (EME2000 ~ J2000 axes), unit
  // 1-sigma about the body axes x, y, z [arcsec]; written as a SIGMA_ARCSEC comment, read back.
  std::optional<Eigen::Vector3d> sigma_arcsec;
};

// One segment: its own metadata comments (after header.comments) and samples.
struct AemBlock {
  std::vector<std::string> comments;
  std::string interpolation_method;  // e.g. "LINEAR"; omitted when empty
  int interpolation_degree = 0;      // written with interpolation_method when > 0
  std::vector<AemSample> samples;
};

// Writes a one-segment AEM with START_TIME/STOP_TIME = first/last epoch. InvalidArgument naming
// the field for an empty OBJECT_NAME/OBJECT_ID/ORIGINATOR, no samples, epochs not strictly
// increasing ("samples[3].epoch: ..."), or a non-finite or non-unit (1e-6) quaternion or a
// non-finite sigma.
absl::StatusOr<std::string> WriteAem(const AemHeader& header, const std::vector<AemSample>& samples);
// One segment per block (header.comments in each); the same errors, "blocks[i].samples[j]..."
// for a sample, "blocks[i].samples" for an empty block, "blocks" for none, and
// "blocks[i].samples[0].epoch" when a block does not start after the previous one ends.
absl::StatusOr<std::string> WriteAemBlocks(const AemHeader& header,
                                           const std::vector<AemBlock>& blocks);

// A parsed, validated AEM.
struct AemSegment {
  std::map<std::string, std::string> metadata;  // keyword -> value (COMMENT excluded)
  std::map<std::string, int> metadata_lines;    // keyword -> its line (1-based)
  // UTC (converted when TIME_SYSTEM is TAI), as are the samples' epochs.
  absl::Time start_time;
  absl::Time stop_time;
  // Quaternions as q_in_b (frame A = inertial, B = body); sigma_arcsec from the data section's
  // SIGMA_ARCSEC comments where one names the sample's epoch.
  std::vector<AemSample> samples;
  std::vector<std::string> comments;  // the metadata section's COMMENT lines, text only
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
// spacecraft-body frame (SC_BODY_<n>); TIME_SYSTEM UTC, or TAI with every epoch converted to UTC
// (ERFA's leap seconds; second 60 refused in TAI), any other of the standard's time systems
// (SCLK, GPS, TT, ...) refused on its line; START_TIME <= STOP_TIME, USEABLE_START/STOP_TIME inside
// them; ATTITUDE_TYPE QUATERNION (the only type this reader decodes); data lines: an epoch and 4
// numbers, epochs strictly increasing and inside [START_TIME, STOP_TIME], quaternion norm 1 within
// 1e-6; a SIGMA_ARCSEC comment with an epoch and 3 finite values (else an error). Errors:
// InvalidArgument "line <n>: <keyword or field>: <reason>".
absl::StatusOr<AemFile> ParseAem(absl::string_view text);

// A planned attitude of spacecraft `spacecraft_id` (`esg predict --planned FILE`): ParseAem, then
// each segment must be that spacecraft's, its OBJECT_NAME or OBJECT_ID equal to spacecraft_id
// (exactly, case included), else InvalidArgument "line <n>: OBJECT_NAME: ..." naming the line of
// the segment's OBJECT_NAME and both values. The samples of every segment in file order (UTC).
absl::StatusOr<std::vector<AemSample>> ParseAemPlan(absl::string_view text,
                                                    absl::string_view spacecraft_id);

}  // namespace esg::storage

#endif  // ESG_FORMATS_AEM_H_
