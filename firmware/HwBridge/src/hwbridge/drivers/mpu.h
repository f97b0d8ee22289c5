// MPU-6050 / MPU-9250 IMU over I2C (hwbridge_msgs/ImuRaw): raw registers, converted to SI units
// by the `mpu6050` / `mpu9250` device plugins' host node.
//
//   #include <Wire.h>
//   hwbridge::drivers::Mpu<TwoWire> imu(Wire);             // address 0x68 (AD0 low)
//   Wire.begin();
//   imu.begin(hwbridge::drivers::kMpu6050, 2, 250);        // setup(): +-2 g, +-250 deg/s
//   if (imu.read()) imu.fill(raw_msg);                     // loop(): a 14-byte burst
//
// begin() checks WHO_AM_I (0x68 on the 6050, 0x71 on the 9250), wakes the chip (PWR_MGMT_1 = 0:
// the 6050 powers up asleep), sets the full scales in GYRO_CONFIG / ACCEL_CONFIG bits 4:3 and,
// on a 9250 asked for its magnetometer, puts the AK8963 on the bus (bypass), reads its fuse-ROM
// sensitivity adjustment and starts it measuring continuously at 100 Hz with 16-bit output -
// the same register writes as the emulated board. read() takes one 14-byte burst from 0x3B
// (big-endian) and, with the magnetometer, ST1 and, when it is ready, the 7 bytes from HXL
// (little-endian, ST2 last). The Wire class is a template parameter (Arduino's TwoWire or
// anything with its beginTransmission/write/endTransmission/requestFrom/read).
#ifndef HWBRIDGE_DRIVERS_MPU_H
#define HWBRIDGE_DRIVERS_MPU_H

#include <stdint.h>

namespace hwbridge {
namespace drivers {

enum MpuChip : uint8_t { kMpu6050 = 0, kMpu9250 = 1 };  // hwbridge_msgs/ImuRaw.chip

/** Registers and values (DEVICES.md; the MPU-6050 / MPU-9250 register maps, AK8963 datasheet). */
namespace mpu {
const uint8_t kAddress = 0x68;
const uint8_t kAddressAlt = 0x69;
const uint8_t kGyroConfig = 0x1B;
const uint8_t kAccelConfig = 0x1C;
const uint8_t kIntPinCfg = 0x37;
const uint8_t kAccelXoutH = 0x3B;
const uint8_t kUserCtrl = 0x6A;
const uint8_t kPwrMgmt1 = 0x6B;
const uint8_t kWhoAmI = 0x75;
const uint8_t kWhoAmI6050 = 0x68;
const uint8_t kWhoAmI9250 = 0x71;
const uint8_t kBypassEn = 0x02;
const uint8_t kAk8963 = 0x0C;
const uint8_t kAkWia = 0x00;
const uint8_t kAkWiaValue = 0x48;
const uint8_t kAkSt1 = 0x02;
const uint8_t kAkHxl = 0x03;
const uint8_t kAkCntl1 = 0x0A;
const uint8_t kAkAsax = 0x10;
const uint8_t kAkPowerDown = 0x00;
const uint8_t kAkFuseRom = 0x0F;
const uint8_t kAkContinuous100Hz16Bit = 0x16;

/** The full-scale select (bits 4:3 of ACCEL_CONFIG) for +-g: 2, 4, 8, 16; 0xFF for another. */
inline uint8_t accel_select(uint8_t range_g) {
  switch (range_g) {
    case 2: return 0;
    case 4: return 1;
    case 8: return 2;
    case 16: return 3;
    default: return 0xFF;
  }
}
/** The full-scale select (bits 4:3 of GYRO_CONFIG) for +-deg/s: 250, 500, 1000, 2000. */
inline uint8_t gyro_select(uint16_t range_dps) {
  switch (range_dps) {
    case 250: return 0;
    case 500: return 1;
    case 1000: return 2;
    case 2000: return 3;
    default: return 0xFF;
  }
}
}  // namespace mpu

/** What begin() found wrong (0: nothing). */
enum MpuError : uint8_t {
  kMpuOk = 0,
  kMpuNoAnswer = 1,      // no ACK at the address
  kMpuWrongChip = 2,     // WHO_AM_I is not the chip asked for
  kMpuBadRange = 3,      // a full scale the chip does not have
  kMpuNoMagnetometer = 4 // the AK8963 did not answer with WIA 0x48
};

template <class WireT>
class Mpu {
 public:
  explicit Mpu(WireT& wire, uint8_t address = mpu::kAddress) : wire_(wire), address_(address) {}

  /** Configure the chip; kMpuOk or what failed (then read() returns false). */
  MpuError begin(MpuChip chip, uint8_t accel_range_g = 2, uint16_t gyro_range_dps = 250,
                 bool magnetometer = true) {
    ok_ = false;
    chip_ = chip;
    mag_ = chip == kMpu9250 && magnetometer;
    uint8_t a = mpu::accel_select(accel_range_g), g = mpu::gyro_select(gyro_range_dps);
    if (a == 0xFF || g == 0xFF) return kMpuBadRange;
    uint8_t who = 0;
    if (!read_regs(address_, mpu::kWhoAmI, &who, 1)) return kMpuNoAnswer;
    if (who != (chip == kMpu9250 ? mpu::kWhoAmI9250 : mpu::kWhoAmI6050)) return kMpuWrongChip;
    if (!write_reg(address_, mpu::kPwrMgmt1, 0x00)) return kMpuNoAnswer;  // wake
    if (!write_reg(address_, mpu::kGyroConfig, static_cast<uint8_t>(g << 3))) return kMpuNoAnswer;
    if (!write_reg(address_, mpu::kAccelConfig, static_cast<uint8_t>(a << 3))) return kMpuNoAnswer;
    accel_config_ = static_cast<uint8_t>(a << 3);
    gyro_config_ = static_cast<uint8_t>(g << 3);
    if (mag_) {
      MpuError e = begin_magnetometer();
      if (e != kMpuOk) return e;
    }
    ok_ = true;
    return kMpuOk;
  }

  /** One reading: the burst, and the magnetometer's newest measurement if there is one.
      False if the chip did not answer (the previous values are kept). */
  bool read() {
    if (!ok_) return false;
    uint8_t raw[14];
    if (!read_regs(address_, mpu::kAccelXoutH, raw, sizeof raw)) return false;
    for (uint8_t i = 0; i < 7; ++i) {
      burst_[i] = static_cast<int16_t>(static_cast<uint16_t>(raw[2 * i] << 8) | raw[2 * i + 1]);
    }
    mag_valid_ = false;
    if (mag_) {
      uint8_t st1 = 0;
      if (read_regs(mpu::kAk8963, mpu::kAkSt1, &st1, 1) && (st1 & 0x01)) {
        uint8_t m[7];
        if (read_regs(mpu::kAk8963, mpu::kAkHxl, m, sizeof m)) {
          for (uint8_t i = 0; i < 3; ++i) {
            mag_data_[i] =
                static_cast<int16_t>(static_cast<uint16_t>(m[2 * i + 1] << 8) | m[2 * i]);
          }
          mag_st2_ = m[6];
          mag_valid_ = true;
        }
      }
    }
    return true;
  }

  /** Fill a hwbridge_msgs/ImuRaw (any struct with its fields) from the last read(). */
  template <class Msg>
  void fill(Msg& msg) const {
    msg.chip = chip_;
    msg.accel_config = accel_config_;
    msg.gyro_config = gyro_config_;
    for (uint8_t i = 0; i < 7; ++i) msg.burst[i] = burst_[i];
    for (uint8_t i = 0; i < 3; ++i) {
      msg.mag[i] = mag_valid_ ? mag_data_[i] : 0;
      msg.mag_asa[i] = mag_valid_ ? asa_[i] : 0;
    }
    msg.mag_st2 = mag_valid_ ? mag_st2_ : 0;
    msg.mag_valid = mag_valid_;
  }

  /** ACCEL X, Y, Z, TEMP, GYRO X, Y, Z of the last read(). */
  const int16_t* burst() const { return burst_; }
  bool mag_valid() const { return mag_valid_; }
  const int16_t* mag() const { return mag_data_; }
  const uint8_t* mag_asa() const { return asa_; }
  uint8_t mag_st2() const { return mag_st2_; }
  bool ok() const { return ok_; }

 private:
  MpuError begin_magnetometer() {
    if (!write_reg(address_, mpu::kUserCtrl, 0x00)) return kMpuNoAnswer;   // I2C master off
    if (!write_reg(address_, mpu::kIntPinCfg, mpu::kBypassEn)) return kMpuNoAnswer;
    uint8_t wia = 0;
    if (!read_regs(mpu::kAk8963, mpu::kAkWia, &wia, 1) || wia != mpu::kAkWiaValue) {
      return kMpuNoMagnetometer;
    }
    // Power-down between modes, fuse ROM for ASA, power-down, continuous 100 Hz 16-bit.
    if (!write_reg(mpu::kAk8963, mpu::kAkCntl1, mpu::kAkPowerDown) ||
        !write_reg(mpu::kAk8963, mpu::kAkCntl1, mpu::kAkFuseRom) ||
        !read_regs(mpu::kAk8963, mpu::kAkAsax, asa_, 3) ||
        !write_reg(mpu::kAk8963, mpu::kAkCntl1, mpu::kAkPowerDown) ||
        !write_reg(mpu::kAk8963, mpu::kAkCntl1, mpu::kAkContinuous100Hz16Bit)) {
      return kMpuNoMagnetometer;
    }
    return kMpuOk;
  }
  bool write_reg(uint8_t device, uint8_t reg, uint8_t value) {
    wire_.beginTransmission(device);
    wire_.write(reg);
    wire_.write(value);
    return wire_.endTransmission() == 0;
  }
  bool read_regs(uint8_t device, uint8_t reg, uint8_t* out, uint8_t n) {
    wire_.beginTransmission(device);
    wire_.write(reg);
    if (wire_.endTransmission(false) != 0) return false;  // repeated start
    if (wire_.requestFrom(device, n) != n) return false;
    for (uint8_t i = 0; i < n; ++i) out[i] = static_cast<uint8_t>(wire_.read());
    return true;
  }

  WireT& wire_;
  uint8_t address_;
  uint8_t chip_ = kMpu6050;
  uint8_t accel_config_ = 0;
  uint8_t gyro_config_ = 0;
  bool mag_ = false;
  bool ok_ = false;
  bool mag_valid_ = false;
  uint8_t mag_st2_ = 0;
  uint8_t asa_[3] = {0, 0, 0};
  int16_t burst_[7] = {0, 0, 0, 0, 0, 0, 0};
  int16_t mag_data_[3] = {0, 0, 0};
};

}  // namespace drivers
}  // namespace hwbridge

#endif  // HWBRIDGE_DRIVERS_MPU_H
