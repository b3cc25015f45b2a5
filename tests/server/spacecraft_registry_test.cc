// Tests of server/spacecraft_registry.h: find, replace, id order and paging. Pure: no server.
#include "server/spacecraft_registry.h"

#include <memory>
#include <string>
#include <vector>

#include "gtest/gtest.h"

namespace esg::server {
namespace {

struct Record {
  explicit Record(std::string spacecraft_id, int v = 0) : id(std::move(spacecraft_id)), value(v) {}
  const std::string id;
  int value;
};

std::vector<std::string> Ids(const std::vector<std::shared_ptr<Record>>& records) {
  std::vector<std::string> ids;
  for (const auto& r : records) ids.push_back(r->id);
  return ids;
}

TEST(SpacecraftRegistry, FindsReplacesAndListsInIdOrder) {
  SpacecraftRegistry<Record> registry;
  EXPECT_EQ(registry.Find("RDK-1"), nullptr);
  registry.Put(std::make_shared<Record>("RDK-2"));
  registry.Put(std::make_shared<Record>("RDK-1", 1));
  const std::shared_ptr<Record> kept = registry.Find("RDK-1");
  registry.Put(std::make_shared<Record>("RDK-1", 2));
  EXPECT_EQ(kept->value, 1);  // a caller's record outlives its replacement
  EXPECT_EQ(registry.Find("RDK-1")->value, 2);
  EXPECT_EQ(registry.size(), 2);
  EXPECT_EQ(Ids(registry.All()), (std::vector<std::string>{"RDK-1", "RDK-2"}));
}

TEST(SpacecraftRegistry, PagesFollowEachOtherWithoutGapsOrRepeats) {
  SpacecraftRegistry<Record> registry;
  for (const char* id : {"C", "A", "E", "B", "D"}) registry.Put(std::make_shared<Record>(id));
  bool more = false;
  std::vector<std::shared_ptr<Record>> page = registry.Page("", 2, &more);
  EXPECT_EQ(Ids(page), (std::vector<std::string>{"A", "B"}));
  EXPECT_TRUE(more);
  page = registry.Page("B", 2, &more);
  EXPECT_EQ(Ids(page), (std::vector<std::string>{"C", "D"}));
  EXPECT_TRUE(more);
  page = registry.Page("D", 2, &more);
  EXPECT_EQ(Ids(page), (std::vector<std::string>{"E"}));
  EXPECT_FALSE(more);
  // Exactly a page left: no further page announced.
  page = registry.Page("C", 2, &more);
  EXPECT_EQ(Ids(page), (std::vector<std::string>{"D", "E"}));
  EXPECT_FALSE(more);
}

}  // namespace
}  // namespace esg::server
