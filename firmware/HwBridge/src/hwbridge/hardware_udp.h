// The UDP Hardware: the node over any Arduino UDP class (WiFiUDP, EthernetUDP, and WiFiUdp.h's
// BSD-socket stand-in on host builds), in the native protocol's datagram framing
// (PROTOCOL.md 1.13: one frame a datagram, no COBS) and its board discovery (1.14).
//
//   #include <WiFi.h>
//   #include <WiFiUdp.h>
//   #include <HwBridge.h>
//   #include <hwbridge/hardware_udp.h>
//   hwbridge::NodeHandle_<hwbridge::UdpHardware<WiFiUDP> > nh;
//   void setup() {
//     WiFi.begin(SSID, PASS);                                      // the sketch joins the network
//     nh.getHardware().setHost(IPAddress(192, 168, 1, 10));        // or leave it out: discovery
//     nh.initNode(0, "esp32");
//   }
//
// Nothing here waits: sends go out when the node writes a frame, receive() takes what arrived.
#ifndef HWBRIDGE_HARDWARE_UDP_H
#define HWBRIDGE_HARDWARE_UDP_H

#include <Arduino.h>
#include <stddef.h>
#include <stdint.h>

#include "arduino_seed.h"
#include "frame.h"

#if defined(HWBRIDGE_HOST)
#include <unistd.h>
#endif

namespace hwbridge {

/** Counters of a UdpHardware (wrapping). */
struct UdpStats {
  uint32_t datagrams_in;    ///< datagrams taken as frames from the host
  uint32_t datagrams_out;   ///< datagrams sent (to the host or the discovery address)
  uint32_t bad_datagrams;   ///< datagrams that are no frame (CRC, size, version): dropped
  uint32_t foreign;         ///< frames from another address than the host's: dropped
  uint32_t oversize;        ///< datagrams longer than the buffer: dropped (in or out)
  uint32_t send_failures;   ///< sends the UDP class refused (no route, full buffers): lost
  uint32_t discoveries;     ///< times a host was found by discovery (the first frame's source)
};

/**
 * The Hardware of a node on UDP. Udp is the Arduino UDP class (begin, beginPacket, write,
 * endPacket, parsePacket, read, remoteIP, remotePort); its address type is what remoteIP()
 * returns (IPAddress). kBuffer bounds one frame's body both ways: the profile's kMtu + 5 at
 * least (a larger datagram is dropped and counted).
 *
 * Where the frames go:
 * - setHost(ip, port): to that host only, and only its datagrams are taken;
 * - otherwise (discovery, PROTOCOL.md 1.14): to the discovery address (setDiscovery; by
 *   default the broadcast 255.255.255.255 and port 2324) until a valid frame arrives; its
 *   source is then the host. A host silent for kForgetMs (setForgetMs) is forgotten, so a
 *   bridge that moved (or a new one) is found again; a bridge that restarts on the same
 *   address is found at once, as its HELLOs come from there.
 */
template <class Udp, size_t kBuffer = 512>
class UdpHardware {
 public:
  static Udp& declUdp();  // never defined: only for the type below
  typedef decltype(declUdp().remoteIP()) Address;
  /** Tells the node to use datagram framing (detail::IsDatagramSink). */
  static const bool kDatagram = true;
#if defined(HWBRIDGE_HOST)
  /** A host build shares the CPU: the node applies the stall rule (detail::SharesCpu). */
  static const bool kSharesCpu = true;
#endif
  /** The bridge's usual port (`hwbridge connect udp-listen://:2324`). */
  static const uint16_t kDefaultPort = 2324;
  /** A discovered host silent this long is forgotten (its heartbeats come every 100 ms). */
  static const uint32_t kForgetMs = 1000;
  static_assert(kBuffer >= kEnvelope + 24, "kBuffer must hold a frame of the minimum MTU (24)");

  UdpHardware() : discovery_(255, 255, 255, 255) {}

  /** Sends to the bridge at ip:port only (before initNode). */
  void setHost(Address ip, uint16_t port = kDefaultPort) {
    host_ = ip;
    host_port_ = port;
    fixed_ = true;
    known_ = true;
  }
  /** Discovery: where frames go while no host is known (a broadcast address, or a host), and
   * the bridge's port. */
  void setDiscovery(Address ip, uint16_t port = kDefaultPort) {
    discovery_ = ip;
    discovery_port_ = port;
  }
  /** How long a discovered host may stay silent before it is forgotten (default kForgetMs). */
  void setForgetMs(uint32_t ms) { forget_ms_ = ms; }
  /** The local UDP port (0, the default: any free one). Not the bridge's port: other boards'
   * broadcast HELLOs would arrive there. */
  void setLocalPort(uint16_t port) { local_port_ = port; }

  /** The node's init: begins the UDP class on the local port (the network must be up). */
  bool init(uint32_t = 0) {
    ready_ = udp_.begin(local_port_) != 0;
    out_len_ = 0;
    return ready_;
  }

  /** The next frame's body from the host, or nullptr (never blocks). Valid until the next call. */
  const uint8_t* receive(size_t* n) {
    if (!ready_) return nullptr;
    for (uint8_t tries = 0; tries < 4; ++tries) {
      const int size = udp_.parsePacket();
      if (size <= 0) return nullptr;
      if (static_cast<size_t>(size) > kBuffer) {
        ++stats_.oversize;
        continue;  // the next parsePacket() drops what is left of it
      }
      const int got = udp_.read(in_, static_cast<size_t>(size));
      Frame f;
      if (got != size || parse_body(in_, static_cast<size_t>(got), kBuffer, &f) != FrameError::Ok) {
        ++stats_.bad_datagrams;
        continue;
      }
      const Address from = udp_.remoteIP();
      const uint16_t port = udp_.remotePort();
      const uint32_t now = ::millis();
      if (!fixed_ && (!known_ || static_cast<uint32_t>(now - heard_ms_) >= forget_ms_)) {
        if (!known_ || !(from == host_) || port != host_port_) ++stats_.discoveries;
        host_ = from;  // discovery: the first frame's source is the host
        host_port_ = port;
        known_ = true;
      } else if (!(from == host_) || port != host_port_) {  // (== is all every IPAddress has)
        ++stats_.foreign;
        continue;
      }
      heard_ms_ = now;
      ++stats_.datagrams_in;
      *n = static_cast<size_t>(got);
      return in_;
    }
    return nullptr;
  }

  /** The frame writer's sink: one byte of the body being written. */
  void put(uint8_t b) {
    if (out_len_ < kBuffer) {
      out_[out_len_] = b;
    }
    ++out_len_;
  }
  /** The end of one frame: sends its body as one datagram. */
  void endDatagram() {
    const size_t n = out_len_;
    out_len_ = 0;
    if (n > kBuffer) {
      ++stats_.oversize;
      return;
    }
    if (!ready_) return;
    const bool to_host = hostKnown();
    const int began = to_host ? udp_.beginPacket(host_, host_port_) : udp_.beginPacket(discovery_, discovery_port_);
    if (began == 0 || udp_.write(out_, n) != n || udp_.endPacket() == 0) {
      ++stats_.send_failures;
      return;
    }
    ++stats_.datagrams_out;
  }
  void flush() {}
  int read() { return -1; }  // the node reads datagrams with receive()

  uint32_t micros() { return ::micros(); }
  /** Entropy for the session id: the ESPs' random number generator, a host's pid, or else
   * ArduinoHardware's (detail::arduino_seed(): on AVR, an Ethernet shield's Uno say, with the
   * count of boots). */
  uint32_t seed() {
#if defined(ESP32) || defined(ESP8266)
    return static_cast<uint32_t>(esp_random()) ^ ::micros();
#elif defined(HWBRIDGE_HOST)
    return ::micros() ^ static_cast<uint32_t>(getpid()) * 2654435761u;
#else
    return detail::arduino_seed();
#endif
  }

  /** The UDP object (its begin() is called by init). */
  Udp& udp() { return udp_; }
  /** True while frames go to a known host (set, or discovered and heard within kForgetMs). */
  bool hostKnown() const { return fixed_ || (known_ && static_cast<uint32_t>(::millis() - heard_ms_) < forget_ms_); }
  /** The host's address and port (the last discovered one, or the one set). */
  Address hostIP() const { return host_; }
  uint16_t hostPort() const { return host_port_; }
  const UdpStats& stats() const { return stats_; }

 private:
  Udp udp_;
  Address host_{};
  Address discovery_;
  uint16_t host_port_ = kDefaultPort;
  uint16_t discovery_port_ = kDefaultPort;
  uint16_t local_port_ = 0;
  bool fixed_ = false;
  bool known_ = false;
  bool ready_ = false;
  uint32_t heard_ms_ = 0;
  uint32_t forget_ms_ = kForgetMs;
  size_t out_len_ = 0;
  UdpStats stats_{};
  uint8_t in_[kBuffer];
  uint8_t out_[kBuffer];
};

}  // namespace hwbridge

#endif  // HWBRIDGE_HARDWARE_UDP_H
