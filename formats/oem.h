// CCSDS Orbit Ephemeris Message (OEM) in KVN, ODM versions 1.0-3.0 (CCSDS 502.0-B-2/-3): the
// orbit product flight dynamics delivers (docs/formats.md, "Orbit: CCSDS OEM"). A reader and
// validator of the project's own, and a writer (the simulator writes the orbit it flew).
//
// Read: the header (CCSDS_OEM_VERS first; CREATION_DATE and ORIGINATOR required; MESSAGE_ID and
// CLASSIFICATION allowed), then one or more segments, each META_START ... META_STOP (OBJECT_NAME,
// OBJECT_ID, CENTER_NAME, REF_FRAME, TIME_SYSTEM, START_TIME, STOP_TIME required; REF_FRAME_EPOCH,
// USEABLE_START_TIME, USEABLE_STOP_TIME, INTERPOLATION, INTERPOLATION_DEGREE allowed), its data
// lines `epoch X Y Z X_DOT Y_DOT Z_DOT [X_DDOT Y_DDOT Z_DDOT]` [km, km/s, km/s^2], and optional
// covariance blocks (COVARIANCE_START ... COVARIANCE_STOP: EPOCH, COV_REF_FRAME, the 21 numbers of
// the lower triangle in rows of 1 to 6; checked for shape, not used). COMMENT lines where the
// standard allows them. Refused on their line, with the keyword or field named:
//   - CENTER_NAME other than EARTH (the shadow and the sun's geometry are the Earth's);
//   - REF_FRAME other than EME2000, GCRF or ICRF (inertial, aligned with J2000 within 0.1 arcsec,
//     docs/conventions.md's `in`); a rotating (ITRF...) or of-date (TOD, MOD, TEME) frame would
//     need a conversion this reader does not make;
//   - TIME_SYSTEM other than UTC, or TAI (converted to UTC, ccsds_kvn.h);
//   - epochs not increasing within a segment or outside START_TIME..STOP_TIME, a number that is
//     not finite, a line with other than 7 or 10 fields.
#ifndef ESG_FORMATS_OEM_H_
#define ESG_FORMATS_OEM_H_

#include <map>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "estimator/orbit.h"

namespace esg::storage {

struct OemSegment {
  std::map<std::string, std::string> metadata;  // keyword -> value (COMMENT excluded)
  std::map<std::string, int> metadata_lines;    // keyword -> its line (1-based)
  std::vector<std::string> comments;            // the metadata's COMMENT lines, text only
  // UTC (converted when TIME_SYSTEM is TAI), as are the states' times. The useable span is
  // USEABLE_START/STOP_TIME when given, else START/STOP_TIME.
  absl::Time start_time, stop_time, useable_start, useable_stop;
  std::vector<estimator::OrbitState> states;  // in REF_FRAME (J2000 axes) [km, km/s]
  int covariance_blocks = 0;
};
struct OemFile {
  std::string version;                        // "1.0", "2.0" or "3.0"
  std::map<std::string, std::string> header;  // keyword -> value (COMMENT excluded)
  std::vector<OemSegment> segments;
};

absl::StatusOr<OemFile> ParseOem(absl::string_view text);

// The orbit of spacecraft `spacecraft_id` (`esg diagnose --orbit FILE`): ParseOem, then every
// segment must be that spacecraft's (OBJECT_NAME or OBJECT_ID equal to it, else InvalidArgument
// naming OBJECT_NAME's line and both values); each segment an arc over its useable span, in file
// order (a later segment is used where they overlap); the orbit's own checks (estimator/orbit.h)
// reported as "segment <n> (line <m>): ...".
absl::StatusOr<estimator::Orbit> ParseOemOrbit(absl::string_view text,
                                               absl::string_view spacecraft_id);

// The orbit of `spacecraft_id` from several deliveries (the service's stored uploads), each read
// as ParseOemOrbit reads one, their arcs in the order given: a later delivery is used where they
// overlap. Errors as ParseOemOrbit's, headed by the delivery's name (`names[i]`, e.g.
// "orbit 12: "; "delivery i: " when not given).
absl::StatusOr<estimator::Orbit> OrbitFromDeliveries(const std::vector<std::string>& texts,
                                                     const std::vector<std::string>& names,
                                                     absl::string_view spacecraft_id);

struct OemHeader {
  std::string object_name;
  std::string object_id;
  std::string originator = "ESG";
  absl::Time creation_date;
  std::vector<std::string> comments;  // COMMENT lines of the metadata
};
// A version 2.0 OEM of one segment: CENTER_NAME EARTH, REF_FRAME EME2000, TIME_SYSTEM UTC,
// START/STOP_TIME the first and last state's, INTERPOLATION HERMITE of degree 3. InvalidArgument
// naming the field for an empty name, fewer than 2 states, times not increasing or numbers not
// finite.
absl::StatusOr<std::string> WriteOem(const OemHeader& header,
                                     const std::vector<estimator::OrbitState>& states);

}  // namespace esg::storage

#endif  // ESG_FORMATS_OEM_H_
