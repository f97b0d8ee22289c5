// A host stand-in for the Arduino WiFiUDP class (ESP32, ESP8266, WiFiNINA: all share this API)
// over BSD sockets, for host builds: a sketch that runs hwbridge::UdpHardware<WiFiUDP> on a WiFi
// board runs the same code here. IPv4, non-blocking; broadcast allowed. Only on the include path
// of host builds.
#ifndef HWBRIDGE_HOST_WIFIUDP_H
#define HWBRIDGE_HOST_WIFIUDP_H

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "IPAddress.h"

class WiFiUDP {
 public:
  /** The largest datagram received whole (a larger one is cut, as on a board: its CRC fails). */
  static const size_t kMaxDatagram = 1500;

  WiFiUDP() : fd_(-1), out_len_(0), in_len_(0), in_pos_(0), remote_port_(0), dest_port_(0) {}
  ~WiFiUDP() { stop(); }
  WiFiUDP(const WiFiUDP&) = delete;
  WiFiUDP& operator=(const WiFiUDP&) = delete;

  /** Binds to port on every interface (0: any free port); 1 on success, 0 on failure. */
  uint8_t begin(uint16_t port) {
    stop();
    fd_ = ::socket(AF_INET, SOCK_DGRAM, 0);
    if (fd_ < 0) return 0;
    int one = 1;
    setsockopt(fd_, SOL_SOCKET, SO_BROADCAST, &one, sizeof one);
    struct sockaddr_in addr;
    memset(&addr, 0, sizeof addr);
    addr.sin_family = AF_INET;
    addr.sin_addr.s_addr = htonl(INADDR_ANY);
    addr.sin_port = htons(port);
    if (::bind(fd_, reinterpret_cast<struct sockaddr*>(&addr), sizeof addr) != 0) {
      stop();
      return 0;
    }
    fcntl(fd_, F_SETFL, fcntl(fd_, F_GETFL) | O_NONBLOCK);
    return 1;
  }
  void stop() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
    out_len_ = in_len_ = in_pos_ = 0;
  }
  /** Host builds only: the port bound (after begin(0)). */
  uint16_t localPort() const {
    struct sockaddr_in addr;
    socklen_t len = sizeof addr;
    if (fd_ < 0 || getsockname(fd_, reinterpret_cast<struct sockaddr*>(&addr), &len) != 0) return 0;
    return ntohs(addr.sin_port);
  }

  /** Starts a datagram to ip:port; 1 on success. */
  int beginPacket(IPAddress ip, uint16_t port) {
    for (int i = 0; i < 4; ++i) dest_[i] = ip[i];
    dest_port_ = port;
    out_len_ = 0;
    return fd_ >= 0 ? 1 : 0;
  }
  /** Starts a datagram to host:port, host a dotted address or a name. */
  int beginPacket(const char* host, uint16_t port) {
    IPAddress ip;
    if (!ip.fromString(host)) {
      struct addrinfo hints;
      memset(&hints, 0, sizeof hints);
      hints.ai_family = AF_INET;
      hints.ai_socktype = SOCK_DGRAM;
      struct addrinfo* found = nullptr;
      if (getaddrinfo(host, nullptr, &hints, &found) != 0 || found == nullptr) return 0;
      const uint8_t* a = reinterpret_cast<const uint8_t*>(
          &reinterpret_cast<struct sockaddr_in*>(found->ai_addr)->sin_addr.s_addr);
      ip = IPAddress(a[0], a[1], a[2], a[3]);
      freeaddrinfo(found);
    }
    return beginPacket(ip, port);
  }
  size_t write(uint8_t b) { return write(&b, 1); }
  size_t write(const uint8_t* data, size_t n) {
    const size_t room = sizeof out_ - out_len_;
    if (n > room) n = room;
    memcpy(out_ + out_len_, data, n);
    out_len_ += n;
    return n;
  }
  /** Sends the datagram; 1 when the kernel took it (a full buffer or no route loses it: 0). */
  int endPacket() {
    if (fd_ < 0) return 0;
    struct sockaddr_in addr;
    memset(&addr, 0, sizeof addr);
    addr.sin_family = AF_INET;
    memcpy(&addr.sin_addr.s_addr, dest_, 4);
    addr.sin_port = htons(dest_port_);
    const ssize_t sent = ::sendto(fd_, out_, out_len_, 0, reinterpret_cast<struct sockaddr*>(&addr), sizeof addr);
    out_len_ = 0;
    return sent >= 0 ? 1 : 0;
  }

  /** Takes the next datagram (dropping what is left of the last one): its size, or 0 when none
   * is waiting. Never blocks. */
  int parsePacket() {
    in_len_ = in_pos_ = 0;
    if (fd_ < 0) return 0;
    for (;;) {
      struct sockaddr_in addr;
      socklen_t len = sizeof addr;
      const ssize_t n = ::recvfrom(fd_, in_, sizeof in_, 0, reinterpret_cast<struct sockaddr*>(&addr), &len);
      if (n < 0) {
        if (errno == EINTR) continue;
        return 0;  // nothing waiting (or an ICMP error for an earlier send: no datagram)
      }
      if (n == 0) continue;  // an empty datagram: Arduino's parsePacket skips them too
      const uint8_t* a = reinterpret_cast<const uint8_t*>(&addr.sin_addr.s_addr);
      remote_ = IPAddress(a[0], a[1], a[2], a[3]);
      remote_port_ = ntohs(addr.sin_port);
      in_len_ = static_cast<size_t>(n);
      return static_cast<int>(n);
    }
  }
  int available() { return static_cast<int>(in_len_ - in_pos_); }
  int read() { return in_pos_ < in_len_ ? in_[in_pos_++] : -1; }
  int read(unsigned char* buf, size_t n) {
    const size_t left = in_len_ - in_pos_;
    if (n > left) n = left;
    memcpy(buf, in_ + in_pos_, n);
    in_pos_ += n;
    return static_cast<int>(n);
  }
  int read(char* buf, size_t n) { return read(reinterpret_cast<unsigned char*>(buf), n); }
  int peek() { return in_pos_ < in_len_ ? in_[in_pos_] : -1; }
  void flush() { in_pos_ = in_len_; }
  IPAddress remoteIP() const { return remote_; }
  uint16_t remotePort() const { return remote_port_; }

 private:
  int fd_;
  uint8_t out_[kMaxDatagram];
  uint8_t in_[kMaxDatagram];
  size_t out_len_, in_len_, in_pos_;
  IPAddress remote_;
  uint16_t remote_port_;
  uint8_t dest_[4] = {0, 0, 0, 0};
  uint16_t dest_port_;
};

#endif  // HWBRIDGE_HOST_WIFIUDP_H
