// A free TCP port on loopback for a test's server (the OS picks it; a race with another
// process taking it in between stays possible: callers retry or fail with the server's log).
#ifndef ESG_TESTS_TESTING_FREE_PORT_H_
#define ESG_TESTS_TESTING_FREE_PORT_H_

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

namespace esg::testing {

// A TCP port on 127.0.0.1 that was free a moment ago; 0 on failure.
inline int FreeLoopbackPort() {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) return 0;
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  address.sin_port = 0;
  socklen_t length = sizeof address;
  int port = 0;
  if (bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0 &&
      getsockname(fd, reinterpret_cast<sockaddr*>(&address), &length) == 0) {
    port = ntohs(address.sin_port);
  }
  close(fd);
  return port;
}

}  // namespace esg::testing

#endif  // ESG_TESTS_TESTING_FREE_PORT_H_
