// The source of a predicted attitude (esg.v1.AttitudeSource) in words for people: "recorded",
// "planned", "inertial hold". Text a person reads (esg's tables and assumption line, the server's
// PredictResponse.assumption, the AEM's COMMENT lines) uses these words; the proto field and the
// proto JSON mapping (`esg --format json`, the gateway) keep the enum names (docs/service.md,
// "PredictAttitude"). The console's copy of this mapping is PREDICT_SOURCES in
// console/plugin/objects.js.
#ifndef ESG_PROTO_ATTITUDE_SOURCE_WORDS_H_
#define ESG_PROTO_ATTITUDE_SOURCE_WORDS_H_

#include <string_view>

#include "esg/v1/estimation_service.pb.h"

namespace esg::proto_convert {

inline std::string_view AttitudeSourceWords(esg::v1::AttitudeSource source) {
  switch (source) {
    case esg::v1::ATTITUDE_SOURCE_RECORDED:
      return "recorded";
    case esg::v1::ATTITUDE_SOURCE_PLANNED:
      return "planned";
    case esg::v1::ATTITUDE_SOURCE_INERTIAL_HOLD:
      return "inertial hold";
    default:
      return "unspecified";
  }
}

}  // namespace esg::proto_convert

#endif  // ESG_PROTO_ATTITUDE_SOURCE_WORDS_H_
