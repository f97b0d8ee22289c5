// The sketch of tests/firmware/test_identity_e2e.py, built with --board host: a board that names
// itself as a sketch written by `hwbridge firmware generate ROBOT.yaml --board base` does, by
// defining the identity before the library (the test builds it with other values through -D,
// and once with another schema hash, as a board built with another hwbridge version). It
// publishes a counter on `count`.
#ifndef HWBRIDGE_FIRMWARE_NAME
#define HWBRIDGE_FIRMWARE_NAME "demo/base"
#endif
#ifndef HWBRIDGE_BUILD_TAG
#define HWBRIDGE_BUILD_TAG "demo/base@000000000000"
#endif
#include <HwBridge.h>
#include <std_msgs/Int32.h>

hwbridge::NodeHandle_<hwbridge::PosixHardware, hwbridge::ComfortableProfile> nh;
std_msgs::Int32 count_msg;
hwbridge::Publisher<std_msgs::Int32> count("count");
unsigned long last_ms = 0;

void setup() {
  nh.initNode(115200, "ident", "2.3");
  nh.advertise(count);
}

void loop() {
  nh.spinOnce();
  if (nh.connected() && millis() - last_ms >= 100) {
    last_ms = millis();
    ++count_msg.data;
    count.publish(count_msg);
  }
}
