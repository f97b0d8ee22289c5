// A host stand-in for the Arduino core's IPAddress (IPv4), for host builds of sketches that use
// a UDP class (WiFiUdp.h here). Only on the include path of host builds.
#ifndef HWBRIDGE_HOST_IPADDRESS_H
#define HWBRIDGE_HOST_IPADDRESS_H

#include <stdint.h>
#include <stdio.h>

class IPAddress {
 public:
  IPAddress() : bytes_{0, 0, 0, 0} {}
  IPAddress(uint8_t a, uint8_t b, uint8_t c, uint8_t d) : bytes_{a, b, c, d} {}
  uint8_t operator[](int i) const { return bytes_[i & 3]; }
  uint8_t& operator[](int i) { return bytes_[i & 3]; }
  bool operator==(const IPAddress& o) const {
    return bytes_[0] == o.bytes_[0] && bytes_[1] == o.bytes_[1] && bytes_[2] == o.bytes_[2] &&
           bytes_[3] == o.bytes_[3];
  }
  bool operator!=(const IPAddress& o) const { return !(*this == o); }
  /** Parses dotted decimal ("192.168.4.1"); false (and unchanged) for anything else. */
  bool fromString(const char* text) {
    unsigned v[4];
    char extra;
    if (sscanf(text, "%u.%u.%u.%u%c", &v[0], &v[1], &v[2], &v[3], &extra) != 4) return false;
    for (int i = 0; i < 4; ++i) {
      if (v[i] > 255) return false;
    }
    for (int i = 0; i < 4; ++i) bytes_[i] = static_cast<uint8_t>(v[i]);
    return true;
  }

 private:
  uint8_t bytes_[4];
};

#endif  // HWBRIDGE_HOST_IPADDRESS_H
