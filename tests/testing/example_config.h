// A spacecraft configuration of deploy/examples/ read as a user's file is (the JSON of
// docs/formats.md through proto/convert.h), for tests that run on the examples. The including
// target defines ESG_SOURCE_DIR and links esg_proto_convert.
#ifndef ESG_TESTS_TESTING_EXAMPLE_CONFIG_H_
#define ESG_TESTS_TESTING_EXAMPLE_CONFIG_H_

#include <fstream>
#include <sstream>
#include <string>

#include "estimator/spacecraft_config.h"
#include "gtest/gtest.h"
#include "proto/convert.h"

namespace esg::testing {

// deploy/examples/<name>, e.g. "rdk1.json"; a failed read or parse fails the test.
inline estimator::SpacecraftConfig ExampleConfig(const std::string& name) {
  std::ifstream in(std::string(ESG_SOURCE_DIR) + "/deploy/examples/" + name);
  std::stringstream text;
  text << in.rdbuf();
  auto config = proto_convert::ParseConfigJson(text.str());
  EXPECT_TRUE(config.ok()) << name << ": " << config.status();
  return config.ok() ? *config : estimator::SpacecraftConfig{};
}

}  // namespace esg::testing

#endif  // ESG_TESTS_TESTING_EXAMPLE_CONFIG_H_
