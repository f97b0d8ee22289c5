// UdpNode: a board on WiFi (ESP32, ESP8266) talking to the bridge over UDP. Publishes a reliable
// counter on `udp_count` (std_msgs/UInt32: 0, 1, 2, ... each number once, every PERIOD_MS while
// connected) and echoes each number received on `udp_in` back on `udp_echo` (both reliable).
//
//   hwbridge connect udp-listen://:2324       # on the host; the board finds it by broadcast
//   hwbridge topic echo /udp_count
//
// The same sketch builds for the host (`hwbridge firmware build UdpNode --board host`), where
// WiFiUDP is a BSD-socket stand-in and $HWBRIDGE_UDP_HOST / $HWBRIDGE_UDP_DISCOVERY
// ("ADDRESS:PORT") replace the constants below.

// ---- settings -------------------------------------------------------------------------------
const char* const WIFI_SSID = "my-network";
const char* const WIFI_PASS = "my-password";
// The bridge's address ("" to find it: HELLOs go to DISCOVERY_ADDRESS until a bridge answers).
const char* const BRIDGE_HOST = "";
const uint16_t BRIDGE_PORT = 2324;
const char* const DISCOVERY_ADDRESS = "255.255.255.255";
#ifndef PERIOD_MS
#define PERIOD_MS 100
#endif
// ---------------------------------------------------------------------------------------------

#if defined(ESP32)
#include <WiFi.h>
#elif defined(ESP8266)
#include <ESP8266WiFi.h>
#endif
#include <WiFiUdp.h>
#include <HwBridge.h>
#include <hwbridge/hardware_udp.h>
#include <std_msgs/UInt32.h>

hwbridge::NodeHandle_<hwbridge::UdpHardware<WiFiUDP>, hwbridge::ComfortableProfile> nh;
std_msgs::UInt32 count_msg;
std_msgs::UInt32 echo_msg;
hwbridge::Publisher<std_msgs::UInt32> counter("udp_count", true);
hwbridge::Publisher<std_msgs::UInt32> echo("udp_echo", true);

// numbers received and not yet echoed (a full ring drops the newest and counts it)
uint32_t ring[32];
uint8_t ring_head = 0, ring_len = 0;
uint32_t ring_dropped = 0;
void on_in(const std_msgs::UInt32& m) {
  if (ring_len == sizeof ring / sizeof ring[0]) {
    ++ring_dropped;
    return;
  }
  ring[(ring_head + ring_len++) % (sizeof ring / sizeof ring[0])] = m.data;
}
hwbridge::Subscriber<std_msgs::UInt32> in("udp_in", &on_in, true);

uint32_t next_count = 0;
unsigned long last_ms = 0;

/** "A.B.C.D:PORT" or "A.B.C.D" into ip and port; false when it is neither. */
bool parse_address(const char* text, IPAddress* ip, uint16_t* port) {
  char host[40];
  const char* colon = strchr(text, ':');
  const size_t n = colon ? static_cast<size_t>(colon - text) : strlen(text);
  if (n == 0 || n >= sizeof host) return false;
  memcpy(host, text, n);
  host[n] = 0;
  if (colon) *port = static_cast<uint16_t>(atoi(colon + 1));
  return ip->fromString(host);
}

void setup() {
#if defined(ESP32) || defined(ESP8266)
  WiFi.mode(WIFI_STA);
  WiFi.begin(WIFI_SSID, WIFI_PASS);
  while (WiFi.status() != WL_CONNECTED) delay(100);  // setup() only: loop() never waits
#endif
  const char* host = BRIDGE_HOST;
  const char* discovery = DISCOVERY_ADDRESS;
#if defined(HWBRIDGE_HOST)
  if (getenv("HWBRIDGE_UDP_HOST")) host = getenv("HWBRIDGE_UDP_HOST");
  if (getenv("HWBRIDGE_UDP_DISCOVERY")) discovery = getenv("HWBRIDGE_UDP_DISCOVERY");
#endif
  IPAddress ip;
  uint16_t port = BRIDGE_PORT;
  if (host[0] != 0 && parse_address(host, &ip, &port)) {
    nh.getHardware().setHost(ip, port);
  } else if (parse_address(discovery, &ip, &port)) {
    nh.getHardware().setDiscovery(ip, port);
  }
  nh.initNode(0, "udpnode", "1.0");
  nh.advertise(counter);
  nh.advertise(echo);
  nh.subscribe(in);
#if defined(HWBRIDGE_HOST)
  printf("udp port %u\n", nh.getHardware().udp().localPort());
  fflush(stdout);
#endif
}

void loop() {
  nh.spinOnce();
  if (!nh.connected()) return;
  // the echo first: the ring empties before the counter takes the window
  if (ring_len != 0) {
    echo_msg.data = ring[ring_head];
    if (echo.publish(echo_msg)) {  // a full window refuses it: the same number next time
      ring_head = static_cast<uint8_t>((ring_head + 1) % (sizeof ring / sizeof ring[0]));
      --ring_len;
    }
  }
  if (millis() - last_ms >= PERIOD_MS) {
    count_msg.data = next_count;
    if (counter.publish(count_msg)) {
      ++next_count;
      last_ms = millis();
    }
  }
  if (ring_dropped != 0) {
    char text[40];
    snprintf(text, sizeof text, "udp_in: %lu dropped (ring full)", static_cast<unsigned long>(ring_dropped));
    if (nh.logWarn(text)) ring_dropped = 0;
  }
}
