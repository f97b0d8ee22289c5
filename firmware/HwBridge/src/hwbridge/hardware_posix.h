// A POSIX Hardware for host-native builds: the board's byte link over a pseudo-terminal, a
// serial device, or a TCP socket (client or listening). Host builds only (Linux, macOS).
//
// Hardware concept (what the session will use): bool init(...), int read() (a byte, or -1 when
// none is waiting), size_t write(const uint8_t*, size_t), put(uint8_t) (the frame writers'
// sink), flush(), uint32_t micros() (wrapping microsecond clock).
#ifndef HWBRIDGE_HARDWARE_POSIX_H
#define HWBRIDGE_HARDWARE_POSIX_H

#if defined(__AVR__)
#error "hardware_posix.h is for host-native builds; boards use the Arduino Hardware"
#endif

#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/types.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#ifndef MSG_NOSIGNAL
#define MSG_NOSIGNAL 0
#endif

namespace hwbridge {

/**
 * init(target) opens one of:
 * - "pty": a new pseudo-terminal; device_path() is the path to give the host
 *   (`hwbridge connect /dev/pts/N`);
 * - "socket://HOST:PORT" (or "tcp://HOST:PORT"): connects to a TCP server;
 * - "listen://[HOST:]PORT" (or "tcp-listen://..."): serves one client at a time on TCP (the
 *   host connects with socket://HOST:PORT; port 0 picks one: local_port()); a client is
 *   accepted without blocking, and after it leaves the next one is;
 * - anything else: a serial device or pty path, set to raw mode (and `baud` if it is a tty).
 * Errors: init returns false and error() says why (errno kept).
 */
class PosixHardware {
 public:
  /** A host program shares the CPU: the node applies the stall rule (detail::SharesCpu). */
  static const bool kSharesCpu = true;

  PosixHardware()
      : fd_(-1), listen_fd_(-1), slave_fd_(-1), out_len_(0), in_len_(0), in_pos_(0), port_(0),
        is_socket_(false) {
    path_[0] = 0;
    error_ = "";
    start_ = now_us();
  }
  ~PosixHardware() { close(); }

  bool init(const char* target = "pty", uint32_t baud = 115200) {
    close();
    start_ = now_us();
    if (strcmp(target, "pty") == 0) return open_pty();
    if (strncmp(target, "socket://", 9) == 0) return open_tcp(target + 9, false);
    if (strncmp(target, "tcp://", 6) == 0) return open_tcp(target + 6, false);
    if (strncmp(target, "listen://", 9) == 0) return open_tcp(target + 9, true);
    if (strncmp(target, "tcp-listen://", 13) == 0) return open_tcp(target + 13, true);
    return open_path(target, baud);
  }

  /**
   * The node's init(baud): opens $HWBRIDGE_LINK (any target above; default "pty") and prints,
   * as one line on stdout, the URL the host connects to: "serial:///dev/pts/N" for a new pty,
   * else the target itself.
   */
  bool init(uint32_t baud) {
    const char* target = getenv("HWBRIDGE_LINK");
    if (target == nullptr || target[0] == 0) target = "pty";
    if (!init(target, baud)) {
      fprintf(stderr, "hwbridge: cannot open %s: %s\n", target, error());
      return false;
    }
    if (strcmp(target, "pty") == 0) {
      printf("serial://%s\n", device_path());
    } else {
      printf("%s\n", target);
    }
    fflush(stdout);
    return true;
  }

  /** Entropy for the session id. */
  uint32_t seed() {
    uint64_t t = now_us();
    return static_cast<uint32_t>(t ^ (t >> 32)) ^ static_cast<uint32_t>(getpid()) * 2654435761u;
  }

  void close() {
    flush();
    if (fd_ >= 0) ::close(fd_);
    if (listen_fd_ >= 0) ::close(listen_fd_);
    if (slave_fd_ >= 0) ::close(slave_fd_);
    fd_ = listen_fd_ = slave_fd_ = -1;
    out_len_ = in_len_ = in_pos_ = 0;
  }

  /** One byte, or -1 when none is waiting (never blocks). */
  int read() {
    if (in_pos_ < in_len_) return in_[in_pos_++];
    if (!ready()) return -1;
    const ssize_t n = is_socket_ ? ::recv(fd_, in_, sizeof in_, 0) : ::read(fd_, in_, sizeof in_);
    if (n > 0) {
      in_len_ = static_cast<size_t>(n);
      in_pos_ = 1;
      return in_[0];
    }
    if (n == 0 && is_socket_) drop_client();  // the peer closed
    if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR && is_socket_) drop_client();
    return -1;
  }

  /** Writes n bytes (after anything put() buffered); returns how many went out. */
  size_t write(const uint8_t* data, size_t n) {
    flush();
    return raw_write(data, n);
  }
  /** Buffers one byte (the sink of write_frame); flush() or a full buffer sends them. */
  void put(uint8_t b) {
    if (out_len_ == sizeof out_) flush();
    out_[out_len_++] = b;
  }
  void flush() {
    if (out_len_ == 0) return;
    raw_write(out_, out_len_);
    out_len_ = 0;
  }

  /** Microseconds since init, wrapping like Arduino's micros(). */
  uint32_t micros() const { return static_cast<uint32_t>(now_us() - start_); }

  /** The pty path to give the host (after init("pty")), else the path opened. */
  const char* device_path() const { return path_; }
  /** The TCP port listened on (after init("listen://...")). */
  uint16_t local_port() const { return port_; }
  /** True while bytes can be exchanged (a listening end: a client is connected). */
  bool connected() { return ready(); }
  int fd() const { return fd_; }
  const char* error() const { return error_; }

 private:
  static uint64_t now_us() {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return static_cast<uint64_t>(ts.tv_sec) * 1000000u + static_cast<uint64_t>(ts.tv_nsec) / 1000u;
  }

  bool fail(const char* why) {
    error_ = why;
    const int saved = errno;
    close();
    errno = saved;
    return false;
  }

  static bool set_raw(int fd, uint32_t baud) {
    struct termios t;
    if (tcgetattr(fd, &t) != 0) return false;
    cfmakeraw(&t);
    t.c_cc[VMIN] = 0;
    t.c_cc[VTIME] = 0;
    speed_t speed = B115200;
    switch (baud) {
      case 9600: speed = B9600; break;
      case 19200: speed = B19200; break;
      case 38400: speed = B38400; break;
      case 57600: speed = B57600; break;
      case 230400: speed = B230400; break;
      default: break;
    }
    cfsetispeed(&t, speed);
    cfsetospeed(&t, speed);
    return tcsetattr(fd, TCSANOW, &t) == 0;
  }

  bool open_pty() {
    fd_ = posix_openpt(O_RDWR | O_NOCTTY);
    if (fd_ < 0) return fail("posix_openpt failed");
    if (grantpt(fd_) != 0 || unlockpt(fd_) != 0) return fail("grantpt/unlockpt failed");
    const char* name = ptsname(fd_);
    if (name == nullptr || strlen(name) >= sizeof path_) return fail("ptsname failed");
    strcpy(path_, name);
    // Keep the slave open ourselves: the master then never reads EIO while no host is attached,
    // and the slave stays in raw mode for whoever opens it next.
    slave_fd_ = ::open(path_, O_RDWR | O_NOCTTY);
    if (slave_fd_ < 0 || !set_raw(slave_fd_, 115200)) return fail("cannot set the pty to raw mode");
    fcntl(fd_, F_SETFL, fcntl(fd_, F_GETFL) | O_NONBLOCK);
    is_socket_ = false;
    return true;
  }

  bool open_path(const char* path, uint32_t baud) {
    if (strlen(path) >= sizeof path_) return fail("path too long");
    strcpy(path_, path);
    fd_ = ::open(path, O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (fd_ < 0) return fail("cannot open the device");
    if (isatty(fd_) && !set_raw(fd_, baud)) return fail("cannot set the device to raw mode");
    is_socket_ = false;
    return true;
  }

  bool open_tcp(const char* where, bool listening) {
    char host[128];
    const char* colon = strrchr(where, ':');
    const char* port_text = colon ? colon + 1 : where;
    const size_t host_len = colon ? static_cast<size_t>(colon - where) : 0;
    if (host_len >= sizeof host) return fail("host name too long");
    memcpy(host, where, host_len);
    host[host_len] = 0;
    if (host_len == 0) strcpy(host, listening ? "127.0.0.1" : "localhost");
    if (host[0] == '[') {  // [::1]
      memmove(host, host + 1, strlen(host));
      char* end = strchr(host, ']');
      if (end) *end = 0;
    }
    struct addrinfo hints;
    memset(&hints, 0, sizeof hints);
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    hints.ai_flags = listening ? AI_PASSIVE : 0;
    struct addrinfo* found = nullptr;
    if (getaddrinfo(host, port_text, &hints, &found) != 0 || found == nullptr) {
      return fail("cannot resolve the TCP address");
    }
    int fd = -1;
    for (struct addrinfo* a = found; a != nullptr; a = a->ai_next) {
      fd = ::socket(a->ai_family, a->ai_socktype, a->ai_protocol);
      if (fd < 0) continue;
      if (listening) {
        int one = 1;
        setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        if (::bind(fd, a->ai_addr, a->ai_addrlen) == 0 && ::listen(fd, 1) == 0) break;
      } else if (::connect(fd, a->ai_addr, a->ai_addrlen) == 0) {
        break;
      }
      ::close(fd);
      fd = -1;
    }
    freeaddrinfo(found);
    if (fd < 0) return fail(listening ? "cannot listen on the TCP address" : "cannot connect");
    is_socket_ = true;
    if (listening) {
      listen_fd_ = fd;
      fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) | O_NONBLOCK);
      struct sockaddr_storage addr;
      socklen_t len = sizeof addr;
      if (getsockname(fd, reinterpret_cast<struct sockaddr*>(&addr), &len) == 0) {
        if (addr.ss_family == AF_INET) {
          port_ = ntohs(reinterpret_cast<struct sockaddr_in*>(&addr)->sin_port);
        } else if (addr.ss_family == AF_INET6) {
          port_ = ntohs(reinterpret_cast<struct sockaddr_in6*>(&addr)->sin6_port);
        }
      }
      return true;
    }
    fd_ = fd;
    client_options();
    return true;
  }

  void client_options() {
    fcntl(fd_, F_SETFL, fcntl(fd_, F_GETFL) | O_NONBLOCK);
    int one = 1;
    setsockopt(fd_, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  }

  /** A connected descriptor exists (accepting a waiting client when listening). */
  bool ready() {
    if (fd_ >= 0) return true;
    if (listen_fd_ < 0) return false;
    fd_ = ::accept(listen_fd_, nullptr, nullptr);
    if (fd_ < 0) return false;
    client_options();
    in_len_ = in_pos_ = 0;
    return true;
  }

  void drop_client() {
    if (listen_fd_ < 0) return;  // a client connection: keep reporting nothing
    ::close(fd_);
    fd_ = -1;
  }

  size_t raw_write(const uint8_t* data, size_t n) {
    if (!ready()) return 0;
    size_t done = 0;
    int stalls = 0;
    while (done < n) {
      const ssize_t w = is_socket_ ? ::send(fd_, data + done, n - done, MSG_NOSIGNAL)
                                   : ::write(fd_, data + done, n - done);
      if (w > 0) {
        done += static_cast<size_t>(w);
        stalls = 0;
        continue;
      }
      if (w < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR) && ++stalls < 1000) {
        usleep(100);  // a full kernel buffer: a board's UART would block too
        continue;
      }
      if (is_socket_) drop_client();
      break;
    }
    return done;
  }

  int fd_;
  int listen_fd_;
  int slave_fd_;
  uint8_t out_[256];
  uint8_t in_[256];
  size_t out_len_;
  size_t in_len_;
  size_t in_pos_;
  uint64_t start_;
  uint16_t port_;
  bool is_socket_;
  char path_[128];
  const char* error_;
};

}  // namespace hwbridge

#endif  // HWBRIDGE_HARDWARE_POSIX_H
