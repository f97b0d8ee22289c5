// The harness of tests/firmware/test_udp_hardware.py, built with --board host: UdpHardware over a
// scripted UDP class, driven by lines on stdin, answering on stdout (one line per command).
//
//   reset                      a new UdpHardware in discovery (discovery address 10.0.0.255:2324)
//   reset A.B.C.D PORT         a new UdpHardware with the host set
//   in A.B.C.D PORT HEX        one datagram arrives from there; answers "got HEX" (the body the
//                              node would get) or "none"
//   frame T F CH SEQ HEX       the node writes a frame (type, frag, channel, seq, payload);
//                              answers "out A.B.C.D PORT HEX" (what was sent) or "none"
//   stats                      "stats IN OUT BAD FOREIGN OVERSIZE FAILURES DISCOVERIES KNOWN"
// The host is never forgotten here (setForgetMs: the longest time): no test depends on the clock.
#include <HwBridge.h>
#include <IPAddress.h>
#include <hwbridge/hardware_udp.h>

class ScriptedUdp {
 public:
  uint8_t begin(uint16_t) { return 1; }
  int beginPacket(IPAddress ip, uint16_t port) {
    to_ = ip;
    to_port_ = port;
    out_len_ = 0;
    return 1;
  }
  size_t write(const uint8_t* p, size_t n) {
    if (n > sizeof out_ - out_len_) n = sizeof out_ - out_len_;
    memcpy(out_ + out_len_, p, n);
    out_len_ += n;
    return n;
  }
  int endPacket() {
    printf("out %u.%u.%u.%u %u ", to_[0], to_[1], to_[2], to_[3], to_port_);
    for (size_t i = 0; i < out_len_; ++i) printf("%02x", out_[i]);
    printf("\n");
    sent_ = true;
    return 1;
  }
  int parsePacket() {
    if (!waiting_) return 0;
    waiting_ = false;
    pos_ = 0;
    return static_cast<int>(in_len_);
  }
  int read(unsigned char* p, size_t n) {
    if (n > in_len_ - pos_) n = in_len_ - pos_;
    memcpy(p, in_ + pos_, n);
    pos_ += n;
    return static_cast<int>(n);
  }
  void flush() { pos_ = in_len_; }
  IPAddress remoteIP() const { return from_; }
  uint16_t remotePort() const { return from_port_; }

  // the script's side
  void arrive(IPAddress from, uint16_t port, const uint8_t* p, size_t n) {
    from_ = from;
    from_port_ = port;
    memcpy(in_, p, n);
    in_len_ = n;
    waiting_ = true;
  }
  bool sent_ = false;

 private:
  IPAddress to_, from_;
  uint16_t to_port_ = 0, from_port_ = 0;
  uint8_t out_[1024];
  uint8_t in_[1024];
  size_t out_len_ = 0, in_len_ = 0, pos_ = 0;
  bool waiting_ = false;
};

typedef hwbridge::UdpHardware<ScriptedUdp, 300> Hardware;
Hardware* hw = nullptr;

size_t unhex(const char* text, uint8_t* out, size_t cap) {
  size_t n = 0;
  unsigned v;
  while (n < cap && text[0] && text[1] && sscanf(text, "%2x", &v) == 1) {
    out[n++] = static_cast<uint8_t>(v);
    text += 2;
  }
  return n;
}

void command(char* line) {
  char hex[2400] = {0};
  unsigned a, b, c, d, port, type, frag, channel, seq;
  uint8_t data[1200];
  if (strncmp(line, "reset", 5) == 0) {
    delete hw;
    hw = new Hardware();
    hw->setDiscovery(IPAddress(10, 0, 0, 255), 2324);
    hw->setForgetMs(0xFFFFFFFFUL);
    if (sscanf(line, "reset %u.%u.%u.%u %u", &a, &b, &c, &d, &port) == 5) {
      hw->setHost(IPAddress(a, b, c, d), static_cast<uint16_t>(port));
    }
    printf("ok %d\n", hw->init(0) ? 1 : 0);
  } else if (sscanf(line, "in %u.%u.%u.%u %u %2399s", &a, &b, &c, &d, &port, hex) == 6) {
    const size_t n = unhex(hex, data, sizeof data);
    hw->udp().arrive(IPAddress(a, b, c, d), static_cast<uint16_t>(port), data, n);
    size_t got = 0;
    const uint8_t* body = hw->receive(&got);
    if (body == nullptr) {
      printf("none\n");
      return;
    }
    printf("got ");
    for (size_t i = 0; i < got; ++i) printf("%02x", body[i]);
    printf("\n");
  } else if (sscanf(line, "frame %u %u %u %u %2399s", &type, &frag, &channel, &seq, hex) >= 4) {
    const size_t n = unhex(hex, data, sizeof data);
    hwbridge::FrameHeader h;
    h.type = static_cast<hwbridge::FrameType>(type);
    h.frag = static_cast<hwbridge::Frag>(frag);
    h.channel = static_cast<uint8_t>(channel);
    h.seq = static_cast<uint8_t>(seq);
    hw->udp().sent_ = false;
    hwbridge::write_frame(*hw, h, data, n);
    if (!hw->udp().sent_) printf("none\n");
  } else if (strncmp(line, "stats", 5) == 0) {
    const hwbridge::UdpStats& s = hw->stats();
    printf("stats %lu %lu %lu %lu %lu %lu %lu %d\n", static_cast<unsigned long>(s.datagrams_in),
           static_cast<unsigned long>(s.datagrams_out), static_cast<unsigned long>(s.bad_datagrams),
           static_cast<unsigned long>(s.foreign), static_cast<unsigned long>(s.oversize),
           static_cast<unsigned long>(s.send_failures), static_cast<unsigned long>(s.discoveries),
           hw->hostKnown() ? 1 : 0);
  } else {
    printf("error %s\n", line);
  }
}

void setup() {
  static char line[2600];
  while (fgets(line, sizeof line, stdin) != nullptr) {
    line[strcspn(line, "\n")] = 0;
    command(line);
    fflush(stdout);
  }
  exit(0);
}

void loop() {}
