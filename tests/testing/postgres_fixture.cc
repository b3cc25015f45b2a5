// The ctest fixture that lets every PostgreSQL test share one server (tests/CMakeLists.txt,
// postgres_server.h PostgresServer::Shared):
//   postgres_fixture start FILE   starts a PostgresServer, writes its port and dir to FILE and
//                                 leaves it running (a server left by an earlier run that was
//                                 interrupted before its cleanup is stopped first)
//   postgres_fixture stop FILE    stops the server FILE names, removes its dir and FILE
// Exit status 0 on success; 1 with the reason on stderr.
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "tests/testing/postgres_server.h"

namespace {

using ::esg::testing::PostgresServer;

// Stops the server `path` names, if any; removes `path`.
void StopPublished(const std::string& path) {
  {
    absl::StatusOr<std::unique_ptr<PostgresServer>> attached =
        PostgresServer::Attach(path, /*take_over=*/true);
    // Destroyed here: stopped, dir removed (also when it no longer answered).
  }
  std::remove(path.c_str());
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 3 || (std::strcmp(argv[1], "start") != 0 && std::strcmp(argv[1], "stop") != 0)) {
    std::fprintf(stderr, "usage: postgres_fixture start|stop FILE\n");
    return 1;
  }
  const std::string path = argv[2];
  StopPublished(path);
  if (std::strcmp(argv[1], "stop") == 0) {
    std::printf("postgres_fixture: stopped the server of %s\n", path.c_str());
    return 0;
  }
  absl::StatusOr<std::unique_ptr<PostgresServer>> server = PostgresServer::Start();
  if (!server.ok()) {
    std::fprintf(stderr, "postgres_fixture: %s\n", server.status().ToString().c_str());
    return 1;
  }
  if (absl::Status published = (*server)->Publish(path); !published.ok()) {
    std::fprintf(stderr, "postgres_fixture: %s\n", published.ToString().c_str());
    return 1;
  }
  std::printf("postgres_fixture: PostgreSQL on 127.0.0.1:%d (%s), named in %s\n", (*server)->port(),
              (*server)->data_dir().c_str(), path.c_str());
  return 0;
}
