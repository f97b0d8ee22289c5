// BME280 temperature / pressure / humidity sensor over I2C (hwbridge_msgs/Bme280): readings
// compensated on the board with the datasheet's integer formulas, published as SI messages by
// the `bme280` device plugin's host node.
//
//   #include <Wire.h>
//   hwbridge::drivers::Bme280<TwoWire> air(Wire);          // address 0x76 (SDO low)
//   Wire.begin();
//   air.begin();                                           // setup(): forced mode, x1
//   if (air.trigger()) ...                                 // loop(): start a measurement,
//   if (air.done() && air.read()) air.fill(raw_msg);       // ... then, once over, read it
//
// begin() checks the chip id (0xD0 = 0x60), reads the trimming parameters once (0x88..0xA1,
// 0xE1..0xE7, H4/H5 unpacked from their shared nibbles), sets the humidity oversampling
// (ctrl_hum 0xF2, effective at the next ctrl_meas write), the standby time (config 0xF5) and
// ctrl_meas (0xF4: osrs_t, osrs_p, mode). In forced mode trigger() writes ctrl_meas with mode
// 01 and done() is true once the chip has gone back to sleep (mode bits 00) and status (0xF3)
// bit 3 `measuring` is clear; in normal mode trigger() and done() are always true. read() takes
// the 8 data bytes from 0xF7 in one burst and compensates them (BME280_compensate_T_int32,
// _P_int64, _H_int32 of the datasheet, section 4.2.3). No heap, no floating point.
#ifndef HWBRIDGE_DRIVERS_BME280_H
#define HWBRIDGE_DRIVERS_BME280_H

#include <stdint.h>

#include "../../hwbridge_wire.h"

namespace hwbridge {
namespace drivers {

/** Registers and values (BME280 datasheet, section 5). */
namespace bme280 {
const uint8_t kAddress = 0x76;
const uint8_t kAddressAlt = 0x77;
const uint8_t kCalibTp = 0x88;  // dig_T1..dig_P9, 24 bytes
const uint8_t kCalibH1 = 0xA1;
const uint8_t kCalibH2 = 0xE1;  // dig_H2..dig_H6, 7 bytes
const uint8_t kId = 0xD0;
const uint8_t kChipId = 0x60;
const uint8_t kReset = 0xE0;
const uint8_t kResetValue = 0xB6;
const uint8_t kCtrlHum = 0xF2;
const uint8_t kStatus = 0xF3;
const uint8_t kCtrlMeas = 0xF4;
const uint8_t kConfig = 0xF5;
const uint8_t kData = 0xF7;  // press msb..hum lsb, 8 bytes
const uint8_t kMeasuring = 0x08;
const uint8_t kModeSleep = 0x00;
const uint8_t kModeForced = 0x01;
const uint8_t kModeNormal = 0x03;

/** The osrs_x code for an oversampling factor 1, 2, 4, 8, 16; 0xFF for another. */
inline uint8_t oversampling_code(uint8_t factor) {
  switch (factor) {
    case 1: return 1;
    case 2: return 2;
    case 4: return 3;
    case 8: return 4;
    case 16: return 5;
    default: return 0xFF;
  }
}

/** Trimming parameters (datasheet table 16). */
struct Calibration {
  uint16_t t1;
  int16_t t2, t3;
  uint16_t p1;
  int16_t p2, p3, p4, p5, p6, p7, p8, p9;
  uint8_t h1;
  int16_t h2;
  uint8_t h3;
  int16_t h4, h5;
  int8_t h6;
};

// the trimming words are little-endian (datasheet table 16): the library's loads
inline uint16_t u16le(const uint8_t* b) { return wire::get16(b); }
inline int16_t s16le(const uint8_t* b) { return static_cast<int16_t>(wire::get16(b)); }

/** Parse 24 bytes from 0x88, the byte at 0xA1 and 7 bytes from 0xE1. */
inline Calibration parse_calibration(const uint8_t* tp, uint8_t h1, const uint8_t* h) {
  Calibration c;
  c.t1 = u16le(tp);
  c.t2 = s16le(tp + 2);
  c.t3 = s16le(tp + 4);
  c.p1 = u16le(tp + 6);
  c.p2 = s16le(tp + 8);
  c.p3 = s16le(tp + 10);
  c.p4 = s16le(tp + 12);
  c.p5 = s16le(tp + 14);
  c.p6 = s16le(tp + 16);
  c.p7 = s16le(tp + 18);
  c.p8 = s16le(tp + 20);
  c.p9 = s16le(tp + 22);
  c.h1 = h1;
  c.h2 = s16le(h);
  c.h3 = h[2];
  // H4 = 0xE4[7:0] << 4 | 0xE5[3:0]; H5 = 0xE6[7:0] << 4 | 0xE5[7:4]; 0xE4, 0xE6 signed.
  c.h4 = static_cast<int16_t>(static_cast<int16_t>(static_cast<int8_t>(h[3])) * 16 | (h[4] & 0x0F));
  c.h5 = static_cast<int16_t>(static_cast<int16_t>(static_cast<int8_t>(h[5])) * 16 | (h[4] >> 4));
  c.h6 = static_cast<int8_t>(h[6]);
  return c;
}

/** The fine temperature the other formulas take (t_fine / 5120 is degC). */
inline int32_t t_fine(int32_t adc_t, const Calibration& c) {
  int32_t var1 = (((adc_t >> 3) - (static_cast<int32_t>(c.t1) << 1)) * static_cast<int32_t>(c.t2)) >> 11;
  int32_t d = (adc_t >> 4) - static_cast<int32_t>(c.t1);
  int32_t var2 = (((d * d) >> 12) * static_cast<int32_t>(c.t3)) >> 14;
  return var1 + var2;
}

/** Temperature in 0.01 degC. */
inline int32_t compensate_t(int32_t fine) { return (fine * 5 + 128) >> 8; }

/** Pressure in Pa as Q24.8; 0 where the formula would divide by zero. */
inline uint32_t compensate_p(int32_t adc_p, int32_t fine, const Calibration& c) {
  int64_t var1 = static_cast<int64_t>(fine) - 128000;
  int64_t var2 = var1 * var1 * static_cast<int64_t>(c.p6);
  var2 = var2 + ((var1 * static_cast<int64_t>(c.p5)) << 17);
  var2 = var2 + (static_cast<int64_t>(c.p4) << 35);
  var1 = ((var1 * var1 * static_cast<int64_t>(c.p3)) >> 8) + ((var1 * static_cast<int64_t>(c.p2)) << 12);
  var1 = ((static_cast<int64_t>(1) << 47) + var1) * static_cast<int64_t>(c.p1) >> 33;
  if (var1 == 0) return 0;
  int64_t p = 1048576 - static_cast<int64_t>(adc_p);
  p = (((p << 31) - var2) * 3125) / var1;
  var1 = (static_cast<int64_t>(c.p9) * (p >> 13) * (p >> 13)) >> 25;
  var2 = (static_cast<int64_t>(c.p8) * p) >> 19;
  p = ((p + var1 + var2) >> 8) + (static_cast<int64_t>(c.p7) << 4);
  return static_cast<uint32_t>(p);
}

/** Relative humidity in %RH as Q22.10, 0..100 %RH. */
inline uint32_t compensate_h(int32_t adc_h, int32_t fine, const Calibration& c) {
  int32_t x = fine - 76800;
  x = ((((adc_h << 14) - (static_cast<int32_t>(c.h4) << 20) - (static_cast<int32_t>(c.h5) * x)) +
        16384) >> 15) *
      (((((((x * static_cast<int32_t>(c.h6)) >> 10) *
            (((x * static_cast<int32_t>(c.h3)) >> 11) + 32768)) >> 10) + 2097152) *
            static_cast<int32_t>(c.h2) + 8192) >> 14);
  x = x - (((((x >> 15) * (x >> 15)) >> 7) * static_cast<int32_t>(c.h1)) >> 4);
  if (x < 0) x = 0;
  if (x > 419430400) x = 419430400;
  return static_cast<uint32_t>(x >> 12);
}
}  // namespace bme280

/** What begin() found wrong (0: nothing). */
enum Bme280Error : uint8_t {
  kBme280Ok = 0,
  kBme280NoAnswer = 1,        // no ACK at the address
  kBme280WrongChip = 2,       // the id is not 0x60
  kBme280BadOversampling = 3  // an oversampling factor the chip does not have
};

template <class WireT>
class Bme280 {
 public:
  explicit Bme280(WireT& wire, uint8_t address = bme280::kAddress)
      : wire_(wire), address_(address) {}

  /** Configure the chip; kBme280Ok or what failed (then trigger() and read() return false).
      Oversampling factors 1, 2, 4, 8 or 16; normal mode measures continuously (0.5 ms
      standby), forced mode once per trigger(). */
  Bme280Error begin(uint8_t osrs_t = 1, uint8_t osrs_p = 1, uint8_t osrs_h = 1,
                    bool normal = false) {
    ok_ = false;
    normal_ = normal;
    uint8_t t = bme280::oversampling_code(osrs_t), p = bme280::oversampling_code(osrs_p),
            h = bme280::oversampling_code(osrs_h);
    if (t == 0xFF || p == 0xFF || h == 0xFF) return kBme280BadOversampling;
    uint8_t id = 0;
    if (!read_regs(bme280::kId, &id, 1)) return kBme280NoAnswer;
    if (id != bme280::kChipId) return kBme280WrongChip;
    uint8_t tp[24], h1 = 0, hb[7];
    if (!read_regs(bme280::kCalibTp, tp, sizeof tp) || !read_regs(bme280::kCalibH1, &h1, 1) ||
        !read_regs(bme280::kCalibH2, hb, sizeof hb)) {
      return kBme280NoAnswer;
    }
    cal_ = bme280::parse_calibration(tp, h1, hb);
    ctrl_meas_ = static_cast<uint8_t>(t << 5 | p << 2);
    if (!write_reg(bme280::kCtrlHum, h) || !write_reg(bme280::kConfig, 0x00) ||
        !write_reg(bme280::kCtrlMeas, static_cast<uint8_t>(
                                          ctrl_meas_ | (normal ? bme280::kModeNormal
                                                               : bme280::kModeSleep)))) {
      return kBme280NoAnswer;
    }
    ok_ = true;
    return kBme280Ok;
  }

  /** Forced mode: start one measurement (normal mode: nothing to do). False if the chip did
      not answer. */
  bool trigger() {
    if (!ok_) return false;
    if (normal_) return true;
    return write_reg(bme280::kCtrlMeas, static_cast<uint8_t>(ctrl_meas_ | bme280::kModeForced));
  }

  /** The measurement is over: the chip is asleep again, not measuring (forced mode). */
  bool done() {
    if (!ok_) return false;
    if (normal_) return true;
    uint8_t regs[2];  // status, ctrl_meas
    if (!read_regs(bme280::kStatus, regs, sizeof regs)) return false;
    return !(regs[0] & bme280::kMeasuring) && (regs[1] & 0x03) == bme280::kModeSleep;
  }

  /** Read and compensate the data registers. False if the chip did not answer (the previous
      values are kept). */
  bool read() {
    if (!ok_) return false;
    uint8_t d[8];
    if (!read_regs(bme280::kData, d, sizeof d)) return false;
    int32_t adc_p = static_cast<int32_t>(static_cast<uint32_t>(d[0]) << 12 |
                                         static_cast<uint32_t>(d[1]) << 4 | d[2] >> 4);
    int32_t adc_t = static_cast<int32_t>(static_cast<uint32_t>(d[3]) << 12 |
                                         static_cast<uint32_t>(d[4]) << 4 | d[5] >> 4);
    int32_t adc_h = static_cast<int32_t>(static_cast<uint16_t>(d[6] << 8 | d[7]));
    int32_t fine = bme280::t_fine(adc_t, cal_);
    temperature_ = bme280::compensate_t(fine);
    pressure_ = bme280::compensate_p(adc_p, fine, cal_);
    humidity_ = bme280::compensate_h(adc_h, fine, cal_);
    return true;
  }

  /** Fill a hwbridge_msgs/Bme280 (any struct with its fields) from the last read(). */
  template <class Msg>
  void fill(Msg& msg) const {
    msg.temperature = temperature_;
    msg.pressure = pressure_;
    msg.humidity = humidity_;
  }

  /** Soft reset (0xB6 to 0xE0): the chip is back at power-on; call begin() again. */
  bool reset() {
    ok_ = false;
    return write_reg(bme280::kReset, bme280::kResetValue);
  }

  int32_t temperature() const { return temperature_; }  // 0.01 degC
  uint32_t pressure() const { return pressure_; }       // Pa, Q24.8
  uint32_t humidity() const { return humidity_; }       // %RH, Q22.10
  const bme280::Calibration& calibration() const { return cal_; }
  bool ok() const { return ok_; }

 private:
  bool write_reg(uint8_t reg, uint8_t value) {
    wire_.beginTransmission(address_);
    wire_.write(reg);
    wire_.write(value);
    return wire_.endTransmission() == 0;
  }
  bool read_regs(uint8_t reg, uint8_t* out, uint8_t n) {
    wire_.beginTransmission(address_);
    wire_.write(reg);
    if (wire_.endTransmission(false) != 0) return false;  // repeated start
    if (wire_.requestFrom(address_, n) != n) return false;
    for (uint8_t i = 0; i < n; ++i) out[i] = static_cast<uint8_t>(wire_.read());
    return true;
  }

  WireT& wire_;
  uint8_t address_;
  bool ok_ = false;
  bool normal_ = false;
  uint8_t ctrl_meas_ = 0;
  bme280::Calibration cal_ = {};
  int32_t temperature_ = 0;
  uint32_t pressure_ = 0;
  uint32_t humidity_ = 0;
};

}  // namespace drivers
}  // namespace hwbridge

#endif  // HWBRIDGE_DRIVERS_BME280_H
