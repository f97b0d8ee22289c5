// Bme280: a BME280 on I2C, paired with the `bme280` device plugin. Ten times a second it
// triggers a forced measurement and, once the chip is asleep again, publishes the compensated
// reading (hwbridge_msgs/Bme280) on `air_raw`; the host node publishes sensor_msgs/Temperature,
// FluidPressure and RelativeHumidity on `temperature`, `pressure` and `humidity`.
// SDA/SCL: A4/A5 on an Uno, 20/21 on a Mega. Set the address, oversampling and the robot file
// alike.
//
//   robot file:  - type: bme280
//                  address: 0x76
//   hwbridge topic echo /temperature
#include <HwBridge.h>
#include <Wire.h>
#include <hwbridge/drivers/bme280.h>
#include <hwbridge_msgs/Bme280.h>

const uint8_t kAddress = hwbridge::drivers::bme280::kAddress;  // 0x76: SDO to GND
const uint8_t kOversampling = 1;
const unsigned long kPeriodMs = 100;

hwbridge::NodeHandle nh;
hwbridge::drivers::Bme280<TwoWire> air(Wire, kAddress);
hwbridge_msgs::Bme280 raw_msg;
hwbridge::Publisher<hwbridge_msgs::Bme280> raw_pub("air_raw");
uint8_t air_error = 0;
bool reported = false;
bool waiting = false;
unsigned long read_ms = 0;

void setup() {
  nh.initNode(115200, "bme280");
  nh.advertise(raw_pub);
  raw_msg.header.frame_id.assign("air_sensor_link");
  Wire.begin();
  Wire.setClock(400000);
  air_error = air.begin(kOversampling, kOversampling, kOversampling);
}

void loop() {
  if (nh.connected() && !reported && air_error != hwbridge::drivers::kBme280Ok) {
    reported = true;
    char line[40];
    snprintf(line, sizeof line, "BME280 not ready: error %u", air_error);
    nh.logError(line);
  }
  if (waiting) {
    if (air.done()) {
      waiting = false;
      if (air.read()) {
        air.fill(raw_msg);
        nh.now(&raw_msg.header.stamp.sec, &raw_msg.header.stamp.nsec);
        ++raw_msg.header.seq;
        raw_pub.publish(raw_msg);
      }
    }
  } else if (millis() - read_ms >= kPeriodMs) {
    read_ms = millis();
    waiting = air.trigger();
  }
  nh.spinOnce();
}
