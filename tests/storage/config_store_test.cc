// Tests of storage/config_store.h: versioned round trip, idempotent re-put, list, errors.
#include "storage/config_store.h"

#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/storage.h"
#include "tests/storage/backend.h"
#include "tests/storage/storage_test_util.h"
#include "tests/testing/status_matchers.h"

namespace esg::storage {
namespace {

using ::esg::storage::testing::BackendTest;
using ::esg::storage::testing::IsOkAndHolds;
using ::esg::storage::testing::T;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::ElementsAre;
using ::testing::Field;
using ::testing::HasSubstr;
using ::testing::IsEmpty;

ConfigRecord Config(const std::string& id, const std::string& json, double at_seconds) {
  ConfigRecord c;
  c.spacecraft_id = id;
  c.config_json = json;
  c.updated_time = T(at_seconds);
  return c;
}

// The ConfigStore tests run on both engines (tests/storage/backend.h).
class ConfigStoreTest : public BackendTest {};
ESG_INSTANTIATE_BACKEND_TEST_SUITE(ConfigStoreTest);

TEST_P(ConfigStoreTest, PutKeepsVersionsAndGetReturnsTheLatest) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  ConfigStore& configs = (*storage)->configs();
  EXPECT_THAT(configs.Get("RDK-1"), StatusIs(absl::StatusCode::kNotFound, HasSubstr("RDK-1")));

  EXPECT_THAT(configs.Put(Config("RDK-1", R"({"workingPair":[1,2]})", 0)), IsOkAndHolds(1));
  EXPECT_THAT(configs.Put(Config("RDK-1", R"({"workingPair":[1,3]})", 10)), IsOkAndHolds(2));
  absl::StatusOr<ConfigRecord> latest = configs.Get("RDK-1");
  ASSERT_THAT(latest, IsOk());
  EXPECT_EQ(latest->spacecraft_id, "RDK-1");
  EXPECT_EQ(latest->version, 2);
  EXPECT_EQ(latest->config_json, R"({"workingPair":[1,3]})");
  EXPECT_EQ(latest->updated_time, T(10));

  absl::StatusOr<std::vector<ConfigRecord>> history = configs.History("RDK-1");
  ASSERT_THAT(history, IsOk());
  EXPECT_THAT(*history, ElementsAre(Field(&ConfigRecord::version, 1),
                                    Field(&ConfigRecord::version, 2)));
  EXPECT_EQ((*history)[0].config_json, R"({"workingPair":[1,2]})");
  EXPECT_THAT(configs.History("nobody"), IsOkAndHolds(IsEmpty()));
}

TEST_P(ConfigStoreTest, RePuttingTheLatestJsonAddsNoVersion) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  ConfigStore& configs = (*storage)->configs();
  ASSERT_THAT(configs.Put(Config("RDK-1", "{}", 0)), IsOkAndHolds(1));
  EXPECT_THAT(configs.Put(Config("RDK-1", "{}", 99)), IsOkAndHolds(1));
  EXPECT_THAT(configs.History("RDK-1"), IsOkAndHolds(::testing::SizeIs(1)));
  absl::StatusOr<ConfigRecord> latest = configs.Get("RDK-1");
  ASSERT_THAT(latest, IsOk());
  EXPECT_EQ(latest->updated_time, T(0));  // the stored version is untouched
  // Going back to an earlier content is a change, hence a new version.
  ASSERT_THAT(configs.Put(Config("RDK-1", "{\"a\":1}", 100)), IsOkAndHolds(2));
  EXPECT_THAT(configs.Put(Config("RDK-1", "{}", 101)), IsOkAndHolds(3));
}

// With a comparison of its own (the server's: the parsed values), a text that says the same as the
// latest version's stores no version and leaves that text as it was; one that does not is a
// new version. The comparison sees the latest stored text and the new one.
TEST_P(ConfigStoreTest, ASameConfigComparisonDecidesWhatIsANewVersion) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  ConfigStore& configs = (*storage)->configs();
  // The same when equal ignoring spaces.
  std::vector<std::pair<std::string, std::string>> seen;
  const ConfigStore::SameConfig same = [&seen](absl::string_view stored, absl::string_view fresh) {
    seen.emplace_back(stored, fresh);
    auto squeeze = [](absl::string_view s) {
      std::string out;
      for (char c : s) {
        if (c != ' ') out.push_back(c);
      }
      return out;
    };
    return squeeze(stored) == squeeze(fresh);
  };
  ASSERT_THAT(configs.Put(Config("RDK-1", R"({"a": 1})", 0), same), IsOkAndHolds(1));
  EXPECT_THAT(seen, IsEmpty());  // nothing stored yet to compare with
  EXPECT_THAT(configs.Put(Config("RDK-1", R"({"a":1})", 5), same), IsOkAndHolds(1));
  EXPECT_THAT(seen, ElementsAre(std::pair<std::string, std::string>(R"({"a": 1})", R"({"a":1})")));
  absl::StatusOr<ConfigRecord> latest = configs.Get("RDK-1");
  ASSERT_THAT(latest, IsOk());
  EXPECT_EQ(latest->config_json, R"({"a": 1})");
  EXPECT_EQ(latest->updated_time, T(0));
  // Without it the texts differ: a new version.
  EXPECT_THAT(configs.Put(Config("RDK-1", R"({"a":1})", 6)), IsOkAndHolds(2));
  // A change is a new version with it too.
  EXPECT_THAT(configs.Put(Config("RDK-1", R"({"a": 2})", 7), same), IsOkAndHolds(3));
  EXPECT_THAT(configs.History("RDK-1"), IsOkAndHolds(::testing::SizeIs(3)));
}

TEST_P(ConfigStoreTest, ListReturnsTheLatestOfEachSpacecraftById) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  ConfigStore& configs = (*storage)->configs();
  ASSERT_THAT(configs.Put(Config("SC-B", "b1", 0)), IsOk());
  ASSERT_THAT(configs.Put(Config("SC-A", "a1", 1)), IsOk());
  ASSERT_THAT(configs.Put(Config("SC-B", "b2", 2)), IsOk());
  absl::StatusOr<std::vector<ConfigRecord>> all = configs.List();
  ASSERT_THAT(all, IsOk());
  ASSERT_EQ(all->size(), 2u);
  EXPECT_EQ((*all)[0].spacecraft_id, "SC-A");
  EXPECT_EQ((*all)[0].config_json, "a1");
  EXPECT_EQ((*all)[1].spacecraft_id, "SC-B");
  EXPECT_EQ((*all)[1].config_json, "b2");
  EXPECT_EQ((*all)[1].version, 2);
}

TEST_P(ConfigStoreTest, RejectsEmptyIdAndUnstorableTime) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  EXPECT_THAT((*storage)->configs().Put(Config("", "{}", 0)),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("config.spacecraft_id")));
  ConfigRecord bad_time = Config("RDK-1", "{}", 0);
  bad_time.updated_time = absl::InfiniteFuture();
  EXPECT_THAT((*storage)->configs().Put(bad_time),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("config.updated_time")));
  EXPECT_THAT((*storage)->configs().List(), IsOkAndHolds(IsEmpty()));
}

}  // namespace
}  // namespace esg::storage
