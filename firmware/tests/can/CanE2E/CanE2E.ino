// The end-to-end sketch of tests/firmware/test_can_board.py, built with --board host: the board
// is CAN node $HWBRIDGE_CAN_NODE (default 5) and reaches the bus through the test's relay at
// $HWBRIDGE_CAN (HOST:PORT). A reliable counter (`counter`, std_msgs/Int32, every 50 ms while
// connected), a subscriber `cmd` whose messages are logged back, a service `ping`
// (std_srvs/Trigger: "pong N"), the parameter `rate` read after each connection, and a
// best-effort `imu` (sensor_msgs/Imu, 320 bytes: six fragments at the native MTU of 64, one
// chained transfer to a host that takes chains, CAN.md 12) every 100 ms, orientation.w counting.
#include <HwBridge.h>
#include <hwbridge/can/can_hardware.h>
#include <hwbridge/can/posix_driver.h>
#include <sensor_msgs/Imu.h>
#include <std_msgs/Int32.h>
#include <std_msgs/String.h>
#include <std_srvs/Trigger.h>
#include <stdlib.h>

typedef hwbridge::can::CanHardware<hwbridge::can::PosixCanDriver> CanLink;
// MTU 64 as the boards on CAN; messages up to 512 bytes (a host program has the RAM)
struct E2EProfile : hwbridge::ComfortableProfile {
  static const uint16_t kMaxMessage = 512;
  static const uint16_t kTxBuffer = 512;
};
hwbridge::NodeHandle_<CanLink, E2EProfile> nh;
sensor_msgs::Imu imu_msg;
hwbridge::Publisher<sensor_msgs::Imu> imu("imu");
unsigned long last_imu_ms = 0;
std_msgs::Int32 count_msg;
hwbridge::Publisher<std_msgs::Int32> counter("counter", true);

char got[40];
bool have_got = false;
void on_cmd(const std_msgs::String& m) {
  snprintf(got, sizeof got, "got %s", m.data.c_str());
  have_got = true;
}
hwbridge::Subscriber<std_msgs::String> cmd("cmd", &on_cmd);

uint16_t pings = 0;
void on_ping(const std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  char text[16];
  snprintf(text, sizeof text, "pong %u", ++pings);
  res.success = true;
  res.message.assign(text);
}
hwbridge::ServiceServer<std_srvs::Trigger> ping("ping", &on_ping);

bool was_connected = false;
unsigned long last_ms = 0;

void setup() {
  const char* node = getenv("HWBRIDGE_CAN_NODE");
  nh.getHardware().setNode(static_cast<uint8_t>(node ? atoi(node) : 5));
  // HWBRIDGE_CAN_FORMAT=1: behave as firmware that predates CAN.md format 2 (interop tests)
  const char* format = getenv("HWBRIDGE_CAN_FORMAT");
  if (format && atoi(format) == 1) nh.getHardware().setFormat(hwbridge::can::kFormat1);
  // HWBRIDGE_CAN_CHAINS=0: behave as CAN.md version-2 firmware (no chained transfers)
  const char* chains = getenv("HWBRIDGE_CAN_CHAINS");
  if (chains && atoi(chains) == 0) nh.getHardware().setChains(false);
  imu_msg.header.frame_id.assign("imu_link");
  imu_msg.linear_acceleration.z = 9.81;
  nh.initNode(0, "canboard", "1.0");
  nh.advertise(counter);
  nh.advertise(imu);
  nh.subscribe(cmd);
  nh.advertiseService(ping);
}

void loop() {
  nh.spinOnce();
  if (!nh.connected()) {
    was_connected = false;
    delay(1);
    return;
  }
  if (!was_connected) {
    was_connected = true;
    int32_t rate = -1;
    char text[40];
    if (nh.getParam("rate", &rate)) {
      snprintf(text, sizeof text, "rate is %ld", static_cast<long>(rate));
    } else {
      snprintf(text, sizeof text, "rate not set");
    }
    nh.logInfo(text);
  }
  if (have_got && nh.logWarn(got)) have_got = false;
  if (millis() - last_ms >= 50) {
    last_ms = millis();
    if (counter.publish(count_msg)) ++count_msg.data;
  }
  if (millis() - last_imu_ms >= 100) {
    last_imu_ms = millis();
    if (imu.publish(imu_msg)) imu_msg.orientation.w += 1.0;
  }
  delay(1);
}
