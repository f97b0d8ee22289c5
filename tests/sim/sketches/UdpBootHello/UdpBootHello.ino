// UdpBootHello: a node on UdpHardware on the Uno, whose UDP class is a stand-in that prints each
// datagram it is given on Serial, one line of hex each. No bridge answers, so the node keeps
// sending HELLOs; each names the session id the node chose at boot. Like an Uno with an Ethernet
// shield, it reads the same clock and the same A0 at every boot: only the count of boots
// (hwbridge/boot_count.h) gives each boot its own id.
#include <HwBridge.h>
#include <IPAddress.h>
#include <hwbridge/hardware_udp.h>

struct SerialPrintedUdp {
  uint8_t begin(uint16_t) { return 1; }
  int beginPacket(IPAddress, uint16_t) { return 1; }
  size_t write(const uint8_t* data, size_t n) {
    static const char kHex[] = "0123456789abcdef";
    for (size_t i = 0; i < n; ++i) {
      Serial.write(kHex[data[i] >> 4]);
      Serial.write(kHex[data[i] & 0x0f]);
    }
    return n;
  }
  int endPacket() {
    Serial.write('\n');
    return 1;
  }
  int parsePacket() { return 0; }
  int read(uint8_t*, size_t) { return 0; }
  IPAddress remoteIP() { return IPAddress(); }
  uint16_t remotePort() { return 0; }
};

hwbridge::NodeHandle_<hwbridge::UdpHardware<SerialPrintedUdp, 64> > nh;

void setup() {
  Serial.begin(115200);
  nh.initNode(0, "udp_boot");
}

void loop() { nh.spinOnce(); }
