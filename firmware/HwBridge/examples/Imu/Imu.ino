// Imu: an MPU-6050 (or MPU-9250) on I2C, paired with the `mpu6050` / `mpu9250` device plugins.
// Publishes the raw registers (hwbridge_msgs/ImuRaw) on `imu_raw` 50 times a second; the host
// node converts them to sensor_msgs/Imu on `imu` (and the 9250's magnetometer to `mag`).
// SDA/SCL: A4/A5 on an Uno, 20/21 on a Mega. Set kChip, the ranges and the robot file alike.
//
//   robot file:  - type: mpu6050
//                  accel_range_g: 2
//                  gyro_range_dps: 250
//   hwbridge topic echo /imu
#include <HwBridge.h>
#include <Wire.h>
#include <hwbridge/drivers/mpu.h>
#include <hwbridge_msgs/ImuRaw.h>

const hwbridge::drivers::MpuChip kChip = hwbridge::drivers::kMpu6050;
const uint8_t kAccelRangeG = 2;
const uint16_t kGyroRangeDps = 250;
const unsigned long kPeriodMs = 20;

hwbridge::NodeHandle nh;
hwbridge::drivers::Mpu<TwoWire> imu(Wire);
hwbridge_msgs::ImuRaw raw_msg;
hwbridge::Publisher<hwbridge_msgs::ImuRaw> raw_pub("imu_raw");
uint8_t imu_error = 0;
bool reported = false;
unsigned long read_ms = 0;

void setup() {
  nh.initNode(115200, "imu");
  nh.advertise(raw_pub);
  raw_msg.header.frame_id.assign("imu_link");
  Wire.begin();
  Wire.setClock(400000);
  imu_error = imu.begin(kChip, kAccelRangeG, kGyroRangeDps);
}

void loop() {
  if (nh.connected() && !reported && imu_error != hwbridge::drivers::kMpuOk) {
    reported = true;
    char line[40];
    snprintf(line, sizeof line, "MPU not ready: error %u", imu_error);
    nh.logError(line);
  }
  if (millis() - read_ms >= kPeriodMs) {
    read_ms = millis();
    if (imu.read()) {
      imu.fill(raw_msg);
      nh.now(&raw_msg.header.stamp.sec, &raw_msg.header.stamp.nsec);
      ++raw_msg.header.seq;
      raw_pub.publish(raw_msg);
    }
  }
  nh.spinOnce();
}
