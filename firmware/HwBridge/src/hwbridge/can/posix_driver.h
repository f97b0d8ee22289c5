// A CAN Driver for host-native builds (tests, simulations): frames travel as text lines over a
// TCP connection, one frame a line in candump's compact form, "1400007F#0102AB" (8 hex digits:
// an extended id; 3: a standard one), "!" alone for an error frame. The peer (a test's relay,
// tests/firmware/can_relay.py) puts them on a python-can bus. Host builds only.
#ifndef HWBRIDGE_CAN_POSIX_DRIVER_H
#define HWBRIDGE_CAN_POSIX_DRIVER_H

// (Nothing on AVR: a board has no sockets.)
#if !defined(__AVR__)

#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "transport.h"

#ifndef MSG_NOSIGNAL
#define MSG_NOSIGNAL 0
#endif

namespace hwbridge {
namespace can {

class PosixCanDriver {
 public:
  PosixCanDriver() : error_frames(0), sent(0), received(0), fd_(-1), in_len_(0) {
    target_[0] = 0;
  }
  ~PosixCanDriver() {
    if (fd_ >= 0) ::close(fd_);
  }

  /** The relay to connect to, "HOST:PORT" (default: $HWBRIDGE_CAN). */
  void setTarget(const char* target) {
    strncpy(target_, target, sizeof(target_) - 1);
    target_[sizeof(target_) - 1] = 0;
  }

  /** Connects to the relay (no acceptance filters here: every frame comes, node is unused). */
  bool begin(uint8_t node = 0) {
    (void)node;
    if (target_[0] == 0) {
      const char* env = getenv("HWBRIDGE_CAN");
      if (env == nullptr) {
        fprintf(stderr, "hwbridge can: set HWBRIDGE_CAN=HOST:PORT\n");
        return false;
      }
      setTarget(env);
    }
    char host[128];
    strncpy(host, target_, sizeof(host) - 1);
    host[sizeof(host) - 1] = 0;
    char* colon = strrchr(host, ':');
    if (colon == nullptr) return false;
    *colon = 0;
    addrinfo hints;
    memset(&hints, 0, sizeof(hints));
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    addrinfo* res = nullptr;
    if (getaddrinfo(host[0] ? host : "127.0.0.1", colon + 1, &hints, &res) != 0) return false;
    for (addrinfo* a = res; a != nullptr; a = a->ai_next) {
      const int fd = ::socket(a->ai_family, a->ai_socktype, a->ai_protocol);
      if (fd < 0) continue;
      if (::connect(fd, a->ai_addr, a->ai_addrlen) == 0) {
        fd_ = fd;
        break;
      }
      ::close(fd);
    }
    freeaddrinfo(res);
    if (fd_ < 0) {
      fprintf(stderr, "hwbridge can: cannot connect to %s: %s\n", target_, strerror(errno));
      return false;
    }
    const int one = 1;
    setsockopt(fd_, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
    fcntl(fd_, F_SETFL, fcntl(fd_, F_GETFL) | O_NONBLOCK);
    return true;
  }

  bool receive(Frame* f) {
    for (;;) {
      // A whole line buffered already?
      for (size_t i = 0; i < in_len_; ++i) {
        if (in_[i] != '\n') continue;
        in_[i] = 0;
        const bool ok = parse(reinterpret_cast<const char*>(in_), f);
        memmove(in_, in_ + i + 1, in_len_ - i - 1);
        in_len_ -= i + 1;
        if (ok) {
          ++received;
          return true;
        }
        i = static_cast<size_t>(-1);  // rescan from the start
      }
      if (fd_ < 0) return false;
      if (in_len_ == sizeof(in_)) in_len_ = 0;  // a line too long: not ours, dropped
      const ssize_t n = ::recv(fd_, in_ + in_len_, sizeof(in_) - in_len_, 0);
      if (n == 0) {
        fprintf(stderr, "hwbridge can: the relay closed the connection\n");
        exit(0);
      }
      if (n < 0) return false;
      in_len_ += static_cast<size_t>(n);
    }
  }

  bool send(const Frame& f, uint8_t priority) {
    (void)priority;  // the relay's bus orders nothing: frames go out as they come
    if (fd_ < 0) return false;
    char line[8 + 1 + 2 * kClassicMtu + 2];
    int pos = snprintf(line, sizeof(line), f.extended ? "%08lX#" : "%03lX#",
                       static_cast<unsigned long>(f.id));
    for (uint8_t i = 0; i < f.len && i < kClassicMtu; ++i) {
      pos += snprintf(line + pos, sizeof(line) - static_cast<size_t>(pos), "%02X", f.data[i]);
    }
    line[pos++] = '\n';
    size_t off = 0;
    while (off < static_cast<size_t>(pos)) {
      const ssize_t n = ::send(fd_, line + off, static_cast<size_t>(pos) - off, MSG_NOSIGNAL);
      if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)) continue;
      if (n <= 0) return false;
      off += static_cast<size_t>(n);
    }
    ++sent;
    return true;
  }

  uint32_t micros() {
    timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return static_cast<uint32_t>(static_cast<uint64_t>(ts.tv_sec) * 1000000u +
                                 static_cast<uint64_t>(ts.tv_nsec) / 1000u);
  }
  uint32_t seed() {
    timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return static_cast<uint32_t>(ts.tv_nsec) ^ static_cast<uint32_t>(getpid()) << 16;
  }

  uint32_t error_frames;
  uint32_t sent;
  uint32_t received;

 private:
  static int hex(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
  }
  bool parse(const char* s, Frame* f) {
    if (s[0] == '!') {
      ++error_frames;
      return false;
    }
    const char* hash = strchr(s, '#');
    if (hash == nullptr) return false;
    const size_t id_len = static_cast<size_t>(hash - s);
    if (id_len != 3 && id_len != 8) return false;
    uint32_t id = 0;
    for (size_t i = 0; i < id_len; ++i) {
      const int v = hex(s[i]);
      if (v < 0) return false;
      id = id << 4 | static_cast<uint32_t>(v);
    }
    const char* d = hash + 1;
    size_t n = 0;
    while (d[0] && d[0] != '\r') {
      const int hi = hex(d[0]);
      const int lo = d[1] ? hex(d[1]) : -1;
      if (hi < 0 || lo < 0 || n == kClassicMtu) return false;
      f->data[n++] = static_cast<uint8_t>(hi << 4 | lo);
      d += 2;
    }
    f->id = id;
    f->extended = id_len == 8;
    f->len = static_cast<uint8_t>(n);
    return true;
  }

  int fd_;
  char target_[160];
  uint8_t in_[512];
  size_t in_len_;
};

}  // namespace can
}  // namespace hwbridge

#endif  // !__AVR__
#endif  // HWBRIDGE_CAN_POSIX_DRIVER_H
