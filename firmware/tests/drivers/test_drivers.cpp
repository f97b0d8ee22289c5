// Host tests of the device drivers (firmware/HwBridge/src/hwbridge/drivers) against the fake
// Arduino core in this folder: encoder edges through the attached interrupts, motor outputs,
// the HC-SR04's trigger and echo timing, the MPU's I2C register traffic, Dynamixel packets
// (DEVICES.md's e-manual vectors) over a fake half-duplex UART.
//
// With the generated message headers on the include path (tests/firmware/test_drivers.py
// generates them), each driver also fills its hwbridge_msgs message, which is printed as
// "MSG <type> <hex>" for the host's decoder to check; "DXL <protocol> <id> <inst> <params>
// <packet>" lines give packets to compare with devices/dynamixel's encoder.
#include "Arduino.h"
#include "../check.h"

#include <hwbridge/drivers/dynamixel.h>
#include <hwbridge/drivers/hcsr04.h>
#include <hwbridge/drivers/motor.h>
#include <hwbridge/drivers/mpu.h>
#include <hwbridge/drivers/quadrature.h>

#include <hwbridge_msgs/ImuRaw.h>
#include <hwbridge_msgs/SonarEcho.h>
#include <hwbridge_msgs/WheelTargets.h>
#include <hwbridge_msgs/WheelTicks.h>

#include <map>
#include <string>
#include <vector>

using namespace hwbridge::drivers;
using check::Bytes;

template <class M>
static void print_msg(const M& m) {
  uint8_t buf[256];
  size_t n = m.serialize(buf, sizeof buf);
  CHECK(n > 0, "%s does not serialize", M::type_name());
  printf("MSG %s %s\n", M::type_name(), check::hex(buf, n).c_str());
}

// ------------------------------------------------------------------------------------------
// Quadrature encoders

// Drive A and B through `steps` quadrature steps (forward: A leads B).
static void turn(uint8_t a, uint8_t b, int steps) {
  static const uint8_t kForward[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  fake::Board& bd = fake::board();
  int pos = 0;
  for (int i = 0; i < 4; ++i) {
    if (kForward[i][0] == bd.level[a] && kForward[i][1] == bd.level[b]) pos = i;
  }
  int dir = steps >= 0 ? 1 : -1;
  for (int i = 0; i != steps; i += dir) {
    pos = (pos + dir + 4) % 4;
    if (kForward[pos][0] != bd.level[a]) fake::drive(a, kForward[pos][0]);
    if (kForward[pos][1] != bd.level[b]) fake::drive(b, kForward[pos][1]);
  }
}

static void test_quadrature() {
  bool skipped;
  // The step table: forward 00 -> 10 -> 11 -> 01 -> 00.
  CHECK(quadrature_step(0, 2, skipped) == 1 && !skipped, "00->10");
  CHECK(quadrature_step(2, 3, skipped) == 1, "10->11");
  CHECK(quadrature_step(3, 1, skipped) == 1, "11->01");
  CHECK(quadrature_step(1, 0, skipped) == 1, "01->00");
  CHECK(quadrature_step(0, 1, skipped) == -1, "00->01");
  CHECK(quadrature_step(2, 2, skipped) == 0 && !skipped, "no change");
  CHECK(quadrature_step(0, 3, skipped) == 0 && skipped, "both changed");

  // Mega: A and B on interrupt pins: x4.
  fake::reset(true);
  typedef QuadratureEncoder<18, 19> Left;
  Left::begin();
  CHECK(Left::decoding() == 4, "x4 with two interrupt pins");
  CHECK(fake::board().mode[18] == INPUT_PULLUP, "pull-up");
  turn(18, 19, 1000);
  CHECK(Left::count() == 1000, "forward 1000 -> %u", Left::count());
  turn(18, 19, -1300);
  CHECK(Left::count() == static_cast<uint16_t>(-300), "back 1300 -> %u", Left::count());
  CHECK(fake::board().interrupts_off == 0, "interrupts enabled again");
  // Wrap at 16 bits.
  Left::reset();
  turn(18, 19, 65536 + 5);
  CHECK(Left::count() == 5, "wraps at 2^16 -> %u", Left::count());
  CHECK(Left::missed() == 0, "no missed edges");
  // Both channels changing at once (an edge missed): counted as missed, not as a step.
  fake::board().level[19] = fake::board().level[19] ? LOW : HIGH;  // B changes unseen...
  fake::drive(18, fake::board().level[18] ? LOW : HIGH);          // ... then A interrupts
  CHECK(Left::missed() == 1, "missed edge counted");

  // 32-bit counter, reversed wheel.
  typedef QuadratureEncoder<20, 21, uint32_t> Right;
  Right::begin(true);
  turn(20, 21, 10);
  CHECK(Right::count() == 0xFFFFFFF6UL, "reversed 32-bit -> %lu", (unsigned long)Right::count());
  CHECK(Right::counter_bits() == 32, "32 bits");

  // Uno: A on pin 2 (interrupt), B on pin 4 (none): x2.
  fake::reset(false);
  typedef QuadratureEncoder<2, 4> UnoLeft;
  UnoLeft::begin();
  CHECK(UnoLeft::decoding() == 2, "x2 with one interrupt pin");
  turn(2, 4, 400);
  CHECK(UnoLeft::count() == 200, "x2 counts every edge of A: %u", UnoLeft::count());
  turn(2, 4, -800);
  CHECK(UnoLeft::count() == static_cast<uint16_t>(-200), "x2 backwards: %u", UnoLeft::count());

  // A on a pin without an interrupt: nothing attached, decoding() says so.
  typedef QuadratureEncoder<6, 3> NoIrq;
  NoIrq::begin();
  CHECK(NoIrq::decoding() == 0 && fake::board().handler[1] == 0, "no interrupt on A");

  // WheelTicks as the emulated board fills it: unsigned 16-bit values in the int32 fields.
  hwbridge_msgs::WheelTicks ticks;
  ticks.header.frame_id.assign("base_link");
  fill_wheel_ticks<UnoLeft, Left>(ticks);
  CHECK(ticks.left == 65336 && ticks.counter_bits == 16, "ticks %ld", (long)ticks.left);
  print_msg(ticks);
}

// ------------------------------------------------------------------------------------------
// Motors

static void test_motors() {
  fake::reset();
  Motor left(5, 7), right(6, 8, 9);  // right: IN1/IN2 driver
  DiffDriveMotors motors(left, right, 20.0f);
  motors.begin();
  fake::Board& b = fake::board();
  CHECK(b.mode[5] == OUTPUT && b.mode[7] == OUTPUT && b.mode[9] == OUTPUT, "outputs");
  CHECK(b.pwm[5] == 0 && b.pwm[6] == 0, "stopped at begin");
  hwbridge_msgs::WheelTargets t;
  t.left = 10.0f;
  t.right = -5.0f;
  motors.command(t);
  CHECK(b.pwm[5] == 128 && b.level[7] == HIGH, "left half forward: %d", b.pwm[5]);
  CHECK(b.pwm[6] == 64 && b.level[8] == LOW && b.level[9] == HIGH, "right quarter back: %d",
        b.pwm[6]);
  motors.command(40.0f, -1e9f);
  CHECK(b.pwm[5] == 255 && b.pwm[6] == 255 && b.level[8] == LOW, "clamped");
  CHECK(speed_to_duty(0.0f / 0.0f, 20.0f) == 0, "NaN -> 0");
  CHECK(speed_to_duty(1.0f, 0.0f) == 0, "no max -> 0");
  // Timeout: 0.5 s without targets stops both.
  fake::advance_us(400000);
  motors.update();
  CHECK(b.pwm[5] == 255 && motors.active(), "still going at 0.4 s");
  fake::advance_us(200000);
  motors.update();
  CHECK(b.pwm[5] == 0 && b.pwm[6] == 0 && !motors.active(), "stopped after 0.5 s");
  // A new calibration applies from the next command.
  motors.set_max_speed(40.0f);
  motors.command(10.0f, 10.0f);
  CHECK(b.pwm[5] == 64 && motors.max_speed() == 40.0f, "recalibrated: %d", b.pwm[5]);
  // Reversed motor: positive duty drives its direction pin low.
  Motor mirrored(10, 11, Motor::kNoPin, true);
  mirrored.begin();
  mirrored.set(100);
  CHECK(b.level[11] == LOW && b.pwm[10] == 100, "reversed");
}

// ------------------------------------------------------------------------------------------
// HC-SR04

template <class Sonar>
static uint32_t measure(uint8_t trig, uint8_t echo, unsigned long delay_us, unsigned long width_us,
                        unsigned long poll_every_us) {
  // Wait for the trigger pulse.
  int guard = 0;
  while (!Sonar::update()) {
    fake::advance_us(poll_every_us);
    CHECK(++guard < 100000, "no trigger");
    if (fake::board().last_low_us[trig] > fake::board().last_high_us[trig] &&
        fake::board().last_high_us[trig] != 0 && fake::board().level[echo] == LOW &&
        fake::board().writes[trig] % 2 == 1)
      break;
  }
  fake::Board& b = fake::board();
  CHECK(b.last_low_us[trig] - b.last_high_us[trig] >= 10, "trigger pulse >= 10 us");
  unsigned long t = 0;
  bool rose = false, fell = false;
  for (guard = 0; guard < 1000000; ++guard) {
    if (!rose && t == delay_us && width_us > 0) {
      fake::drive(echo, HIGH);
      rose = true;
    }
    if (rose && !fell && t == delay_us + width_us) {
      fake::drive(echo, LOW);
      fell = true;
    }
    if (Sonar::update()) return Sonar::echo_us();
    // Time moves by the polling step, stopping at the next echo edge (as a sensor would).
    unsigned long step = poll_every_us;
    unsigned long next = !rose ? delay_us : delay_us + width_us;
    if (width_us > 0 && !fell && next > t && next - t < step) step = next - t;
    fake::advance_us(step);
    t += step;
  }
  check::fail("no measurement");
  return 0;
}

static void test_sonar() {
  // Echo on an interrupt pin: exact edges.
  fake::reset();
  typedef HcSr04<9, 3> Sonar;
  Sonar::begin(66);
  CHECK(Sonar::uses_interrupt(), "interrupt on pin 3");
  fake::board().writes[9] = 1;  // begin wrote LOW once
  uint32_t w = measure<Sonar>(9, 3, 450, 5830, 100);
  CHECK(w == 5830, "1 m echo timed exactly: %lu", (unsigned long)w);
  // Not due again before 66 ms have passed since the last trigger.
  CHECK(!Sonar::update(), "waits for the period");
  unsigned long last = fake::board().last_high_us[9];
  fake::advance_us(30000);
  Sonar::update();
  CHECK(fake::board().last_high_us[9] == last, "no trigger before 66 ms");
  fake::advance_us(40000);
  // No echo at all: 0 after the timeout.
  w = measure<Sonar>(9, 3, 0, 0, 1000);
  CHECK(w == 0 && Sonar::timeouts() == 1, "timeout gives 0: %lu", (unsigned long)w);
  // An echo that never falls: 0 too, and no new trigger while Echo is high.
  fake::advance_us(70000);
  Sonar::update();
  fake::drive(3, HIGH);
  fake::advance_us(45000);
  CHECK(Sonar::update() && Sonar::echo_us() == 0, "stuck echo times out");
  fake::advance_us(100000);
  last = fake::board().last_high_us[9];
  CHECK(!Sonar::update() && fake::board().last_high_us[9] == last, "no trigger while high");
  fake::drive(3, LOW);

  // Echo on a pin without an interrupt: polled, exact to the polling interval.
  fake::reset();
  typedef HcSr04<11, 12> Polled;
  Polled::begin(60);
  CHECK(!Polled::uses_interrupt(), "pin 12 is polled");
  w = measure<Polled>(11, 12, 400, 2000, 20);
  CHECK(w >= 1980 && w <= 2020, "polled width %lu", (unsigned long)w);

  hwbridge_msgs::SonarEcho echo;
  echo.header.frame_id.assign("sonar_link");
  Polled::fill(echo, 20.0f);
  CHECK(echo.echo_us == w, "fill");
  print_msg(echo);
}

// ------------------------------------------------------------------------------------------
// MPU-6050 / MPU-9250 on a fake I2C bus

struct FakeWire {
  // Register files of the devices on the bus (address -> 256 registers).
  std::map<uint8_t, std::vector<uint8_t> > devices;
  std::vector<std::pair<uint8_t, std::pair<uint8_t, uint8_t> > > writes;  // (dev, (reg, value))
  uint8_t target = 0;
  std::vector<uint8_t> tx;
  std::vector<uint8_t> rx;
  size_t rx_at = 0;
  uint8_t pointer[256] = {};

  void beginTransmission(uint8_t address) {
    target = address;
    tx.clear();
  }
  size_t write(uint8_t b) {
    tx.push_back(b);
    return 1;
  }
  uint8_t endTransmission(bool stop = true) {
    (void)stop;
    if (!devices.count(target)) return 2;  // NACK on address
    if (tx.empty()) return 0;
    pointer[target] = tx[0];
    for (size_t i = 1; i < tx.size(); ++i) {
      uint8_t reg = static_cast<uint8_t>(tx[0] + i - 1);
      devices[target][reg] = tx[i];
      writes.push_back(std::make_pair(target, std::make_pair(reg, tx[i])));
      on_write(target, reg, tx[i]);
    }
    return 0;
  }
  uint8_t requestFrom(uint8_t address, uint8_t n) {
    rx.clear();
    rx_at = 0;
    if (!devices.count(address)) return 0;
    for (uint8_t i = 0; i < n; ++i) {
      rx.push_back(devices[address][static_cast<uint8_t>(pointer[address] + i)]);
    }
    return n;
  }
  int read() { return rx_at < rx.size() ? rx[rx_at++] : -1; }

  // The MPU-9250's bypass puts the AK8963 on the bus; its fuse ROM shows in mode 0x0F.
  void on_write(uint8_t dev, uint8_t reg, uint8_t value) {
    if (dev == 0x68 && reg == 0x37 && (value & 0x02) && has_ak) {
      std::vector<uint8_t> ak(256, 0);
      ak[0x00] = 0x48;
      devices[0x0C] = ak;
    }
    if (dev == 0x0C && reg == 0x0A) {
      std::vector<uint8_t>& ak = devices[0x0C];
      bool fuse = value == 0x0F;
      ak[0x10] = fuse ? 0xB0 : 0;
      ak[0x11] = fuse ? 0xB1 : 0;
      ak[0x12] = fuse ? 0xA5 : 0;
      if (value == 0x16) {  // a measurement ready: HX=100, HY=-200, HZ=300, ST2 16-bit
        ak[0x02] = 0x01;
        ak[0x03] = 100;
        ak[0x04] = 0;
        ak[0x05] = 0x38;
        ak[0x06] = 0xFF;
        ak[0x07] = 0x2C;
        ak[0x08] = 0x01;
        ak[0x09] = 0x10;
      }
    }
  }
  bool has_ak = false;
};

static void set_burst(FakeWire& w, const int16_t values[7]) {
  for (int i = 0; i < 7; ++i) {
    w.devices[0x68][0x3B + 2 * i] = static_cast<uint8_t>(static_cast<uint16_t>(values[i]) >> 8);
    w.devices[0x68][0x3B + 2 * i + 1] = static_cast<uint8_t>(values[i] & 0xFF);
  }
}

static void test_mpu() {
  static const int16_t kBurst[7] = {100, -200, 16384, -1000, 131, -262, 0x7FFF};
  // MPU-6050: asleep at reset; begin wakes it and sets the ranges.
  {
    FakeWire wire;
    wire.devices[0x68] = std::vector<uint8_t>(256, 0);
    wire.devices[0x68][0x75] = 0x68;
    wire.devices[0x68][0x6B] = 0x40;
    set_burst(wire, kBurst);
    Mpu<FakeWire> imu(wire);
    CHECK(imu.read() == false, "no read before begin");
    CHECK(imu.begin(kMpu6050, 3, 250) == kMpuBadRange, "3 g is not a range");
    CHECK(imu.begin(kMpu9250) == kMpuWrongChip, "a 6050 is not a 9250");
    CHECK(imu.begin(kMpu6050, 4, 1000) == kMpuOk, "begin");
    CHECK(wire.devices[0x68][0x6B] == 0x00, "woken");
    CHECK(wire.devices[0x68][0x1B] == (2 << 3), "gyro 1000 dps");
    CHECK(wire.devices[0x68][0x1C] == (1 << 3), "accel 4 g");
    CHECK(imu.read(), "read");
    for (int i = 0; i < 7; ++i) CHECK(imu.burst()[i] == kBurst[i], "burst[%d]", i);
    hwbridge_msgs::ImuRaw raw;
    raw.header.frame_id.assign("imu_link");
    imu.fill(raw);
    CHECK(raw.chip == 0 && raw.accel_config == 8 && raw.gyro_config == 16 && !raw.mag_valid, "fill");
    print_msg(raw);
    // The chip disappears: read() fails, values kept.
    wire.devices.erase(0x68);
    CHECK(!imu.read() && imu.burst()[2] == 16384, "no answer");
    Mpu<FakeWire> absent(wire);
    CHECK(absent.begin(kMpu6050) == kMpuNoAnswer, "no chip");
  }
  // MPU-9250 with its AK8963.
  {
    FakeWire wire;
    wire.has_ak = true;
    wire.devices[0x68] = std::vector<uint8_t>(256, 0);
    wire.devices[0x68][0x75] = 0x71;
    set_burst(wire, kBurst);
    Mpu<FakeWire> imu(wire);
    CHECK(imu.begin(kMpu9250, 2, 250, true) == kMpuOk, "9250 begin");
    CHECK(wire.devices[0x68][0x37] == 0x02 && wire.devices[0x68][0x6A] == 0, "bypass");
    CHECK(wire.devices[0x0C][0x0A] == 0x16, "continuous 16-bit");
    CHECK(imu.read() && imu.mag_valid(), "mag read");
    CHECK(imu.mag()[0] == 100 && imu.mag()[1] == -200 && imu.mag()[2] == 300, "mag little-endian");
    CHECK(imu.mag_asa()[0] == 0xB0 && imu.mag_asa()[2] == 0xA5 && imu.mag_st2() == 0x10, "asa");
    hwbridge_msgs::ImuRaw raw;
    raw.header.frame_id.assign("imu_link");
    imu.fill(raw);
    CHECK(raw.chip == 1 && raw.mag_valid && raw.mag[1] == -200, "fill 9250");
    print_msg(raw);
    // No new measurement: mag_valid false.
    wire.devices[0x0C][0x02] = 0;
    CHECK(imu.read() && !imu.mag_valid(), "no DRDY");
    // A 9250 without its magnetometer answering.
    FakeWire bare;
    bare.devices[0x68] = std::vector<uint8_t>(256, 0);
    bare.devices[0x68][0x75] = 0x71;
    Mpu<FakeWire> lone(bare);
    CHECK(lone.begin(kMpu9250) == kMpuNoMagnetometer, "no AK8963");
    CHECK(lone.begin(kMpu9250, 2, 250, false) == kMpuOk, "without the magnetometer");
  }
}

// ------------------------------------------------------------------------------------------
// Dynamixel

static Bytes parse_hex(const char* s) {
  Bytes out;
  unsigned v;
  while (sscanf(s, "%2x", &v) == 1) {
    out.push_back(static_cast<uint8_t>(v));
    s += 2;
    while (*s == ' ') ++s;
  }
  return out;
}

// A UART whose other end answers packets from a table (request bytes -> reply bytes).
struct FakeSerial {
  std::map<Bytes, Bytes> replies;
  Bytes written, pending, rx;
  size_t rx_at = 0;
  uint32_t baud = 0;
  uint8_t dir_pin = 0xFF;
  bool dir_high_while_writing = true;
  bool echo = false;

  void begin(uint32_t b) { baud = b; }
  size_t write(const uint8_t* p, size_t n) {
    if (dir_pin != 0xFF && fake::board().level[dir_pin] != HIGH) dir_high_while_writing = false;
    pending.assign(p, p + n);
    written.insert(written.end(), p, p + n);
    return n;
  }
  void flush() {
    if (echo) rx.insert(rx.end(), pending.begin(), pending.end());
    std::map<Bytes, Bytes>::iterator it = replies.find(pending);
    if (it != replies.end()) rx.insert(rx.end(), it->second.begin(), it->second.end());
    pending.clear();
  }
  int available() { return static_cast<int>(rx.size() - rx_at); }
  int read() { return rx_at < rx.size() ? rx[rx_at++] : -1; }
};

static void dump_packet(uint8_t protocol, uint8_t id, uint8_t inst, const Bytes& params) {
  uint8_t out[64];
  size_t n = dxl::build_packet(protocol, id, inst, params.data(), params.size(), out, sizeof out);
  CHECK(n > 0, "packet builds");
  printf("DXL %u %u %u %s %s\n", protocol, id, inst, check::hex(params.data(), params.size()).c_str(),
         check::hex(out, n).c_str());
}

static void test_dynamixel() {
  uint8_t out[64];
  // DEVICES.md's e-manual vectors, Protocol 2.0.
  size_t n = dxl::build_packet(2, 1, dxl::kPing, nullptr, 0, out, sizeof out);
  CHECK(check::hex(out, n) == "fffffd0001030001194e", "ping %s", check::hex(out, n).c_str());
  const uint8_t read_pos[] = {0x84, 0x00, 0x04, 0x00};
  n = dxl::build_packet(2, 1, dxl::kRead, read_pos, 4, out, sizeof out);
  CHECK(check::hex(out, n) == "fffffd0001070002840004001d15", "read %s", check::hex(out, n).c_str());
  const uint8_t goal[] = {0x74, 0x00, 0x00, 0x02, 0x00, 0x00};
  n = dxl::build_packet(2, 1, dxl::kWrite, goal, 6, out, sizeof out);
  CHECK(check::hex(out, n) == "fffffd0001090003740000020000ca89", "write %s", check::hex(out, n).c_str());
  // Protocol 1.0.
  const uint8_t p1[] = {0x0C, 0x64, 0xAA};
  Bytes v = parse_hex("FFFF0105030C64AADC");
  n = dxl::build_packet(1, 1, 0x03, p1, 3, out, sizeof out);
  CHECK(Bytes(out, out + n) == v, "p1 write %s", check::hex(out, n).c_str());
  n = dxl::build_packet(1, 1, dxl::kPing, nullptr, 0, out, sizeof out);
  CHECK(check::hex(out, n) == "ffff010201fb", "p1 ping");
  // Does not fit: 0, nothing past cap.
  uint8_t small[12];
  CHECK(dxl::build_packet(2, 1, dxl::kWrite, goal, 6, small, sizeof small) == 0, "too small");
  CHECK(dxl::build_packet(3, 1, dxl::kPing, nullptr, 0, out, sizeof out) == 0, "protocol 3");

  // Stuffing: FF FF FD in the parameters gets an extra FD; the parser removes it.
  const uint8_t tricky[] = {0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x01};
  n = dxl::build_packet(2, 1, dxl::kWrite, tricky, 6, out, sizeof out);
  CHECK(check::hex(out, n).find("fffffdfd01") != std::string::npos, "stuffed %s",
        check::hex(out, n).c_str());
  // A status with the same parameters, stuffed, parsed back.
  {
    uint8_t status[32];
    uint8_t body[] = {0x00, 0xFF, 0xFF, 0xFD, 0x07};  // ERR then params
    size_t m = dxl::build_packet(2, 3, dxl::kStatus, body, sizeof body, status, sizeof status);
    dxl::StatusParser<8> parser(2);
    bool done = false;
    const uint8_t noise[] = {0x00, 0xFF, 0x12, 0xFF, 0xFF, 0xFD};
    for (size_t i = 0; i < sizeof noise; ++i) done = parser.feed(noise[i]) || done;
    for (size_t i = 0; i < m; ++i) done = parser.feed(status[i]);
    CHECK(done && parser.id() == 3 && parser.error() == 0 && parser.size() == 4, "stuffed status");
    CHECK(parser.params()[2] == 0xFD && parser.params()[3] == 0x07, "unstuffed");
    status[m - 1] ^= 1;
    for (size_t i = 0; i < m; ++i) done = parser.feed(status[i]);
    CHECK(!done && parser.bad() == 1, "bad CRC refused");
  }
  // Too many parameters for the parser: refused, nothing written past params.
  {
    uint8_t status[64];
    uint8_t body[20] = {0};
    size_t m = dxl::build_packet(2, 1, dxl::kStatus, body, sizeof body, status, sizeof status);
    dxl::StatusParser<4> parser(2);
    bool done = false;
    for (size_t i = 0; i < m; ++i) done = parser.feed(status[i]) || done;
    CHECK(!done && parser.bad() == 1, "oversize status refused");
  }

  // A bus with a direction pin: the e-manual's read of Present Position (166).
  fake::reset();
  FakeSerial serial;
  serial.dir_pin = 2;
  serial.replies[parse_hex("FFFFFD0001070002840004001D15")] =
      parse_hex("FFFFFD000108005500A60000008CC0");
  serial.replies[parse_hex("FFFFFD0001030001194E")] = parse_hex("FFFFFD000107005500060426655D");
  DynamixelBus<FakeSerial> bus(serial, 2, 2);
  bus.begin(57600);
  CHECK(serial.baud == 57600 && fake::board().mode[2] == OUTPUT && fake::board().level[2] == LOW,
        "begin");
  int32_t pos = 0;
  CHECK(bus.read_int(1, 132, pos, 4) && pos == 166, "present position %ld", (long)pos);
  CHECK(serial.dir_high_while_writing && fake::board().level[2] == LOW, "direction pin");
  CHECK(bus.ping(1), "ping answered");
  // No answer: a timeout after 10 ms, counted.
  unsigned long t0 = micros();
  int polls = 0;
  CHECK(bus.send(2, dxl::kPing, nullptr, 0), "send");
  while (bus.poll() == kDxlPending) {
    fake::advance_us(500);
    ++polls;
  }
  CHECK(bus.poll() == kDxlTimeout && bus.timeouts() == 1, "timeout");
  CHECK(micros() - t0 >= 10000 && polls < 30, "timed out after 10 ms");
  // A broadcast write is done at once.
  CHECK(bus.write_u8(dxl::kBroadcast, 64, 1), "broadcast write needs no status");
  // Echo of the own packet skipped.
  serial.echo = true;
  bus.echo(true);
  CHECK(bus.read_int(1, 132, pos, 4) && pos == 166, "with echo");
  // Non-blocking: start, then poll until done; the status read as a signed value.
  serial.echo = false;
  bus.echo(false);
  CHECK(bus.start_read(1, 132, 4), "start_read");
  DxlResult result;
  while ((result = bus.poll()) == kDxlPending) fake::advance_us(100);
  CHECK(result == kDxlDone && bus.status_int(pos, 4) && pos == 166, "polled read %ld", (long)pos);
  CHECK(!bus.status_int(pos, 2), "status of 4 bytes is not 2");
  serial.replies[parse_hex("FFFFFD0001090003740000020000CA89")] = parse_hex("FFFFFD0001040055000000");
  size_t before = serial.written.size();
  CHECK(bus.start_write_int(1, 116, 512, 4), "start_write_int");
  CHECK(Bytes(serial.written.begin() + before, serial.written.end()) ==
            parse_hex("FFFFFD0001090003740000020000CA89"),
        "the e-manual's write of Goal Position 512");
  // Sign extension of a 2-byte value (Present Load -100 = 0xFF9C).
  uint8_t load_status[16];
  const uint8_t load_body[] = {0x00, 0x9C, 0xFF};
  size_t ls = dxl::build_packet(2, 1, dxl::kStatus, load_body, 3, load_status, sizeof load_status);
  serial.replies[parse_hex("FFFFFD00010700027E0002003549")] = Bytes(load_status, load_status + ls);
  int32_t load = 0;
  CHECK(bus.read_int(1, 126, load, 2) && load == -100, "sign-extended %ld", (long)load);

  // Protocol 1.0: the e-manual's read of address 43 (one byte) -> 0x20.
  FakeSerial s1;
  s1.replies[parse_hex("FFFF0104022B01CC")] = parse_hex("FFFF01030020DB");
  DynamixelBus<FakeSerial> bus1(s1, DynamixelBus<FakeSerial>::kNoPin, 1);
  bus1.begin(1000000);
  int32_t temp = 0;
  CHECK(bus1.read_int(1, 43, temp, 1) && temp == 0x20, "p1 read %ld", (long)temp);

  // Position conversions (X: 2048 = 0 rad, 4096 a turn; AX: 512 = 0, 300 deg / 1024).
  CHECK(dxl::x_radians_to_ticks(0.0f) == 2048 && dxl::x_radians_to_ticks(3.14159265f) == 4096,
        "x ticks");
  CHECK(dxl::ax_radians_to_ticks(0.0f) == 512, "ax ticks");
  float r = dxl::x_ticks_to_radians(3072);
  CHECK(r > 1.5707f && r < 1.5709f, "x rad");

  // Packets for the host's encoder to compare.
  dump_packet(2, 1, dxl::kPing, Bytes());
  dump_packet(2, 7, dxl::kRead, parse_hex("84000400"));
  dump_packet(2, 1, dxl::kWrite, parse_hex("740000020000"));
  dump_packet(2, 252, dxl::kWrite, parse_hex("7400FFFFFD00"));
  dump_packet(2, 2, dxl::kWrite, parse_hex("FFFFFDFFFFFDFD"));
  dump_packet(1, 1, dxl::kWrite, parse_hex("0C64AA"));
  dump_packet(1, 253, dxl::kRead, parse_hex("2402"));
}

// Seeded: random status packets (parameters full of FF FF FD) survive build + parse in both
// protocols, with noise between them; random bytes never complete a packet with more
// parameters than the parser holds, and nothing is written past its buffer (ASan).
static void test_dynamixel_parser_random() {
  uint32_t seed = 12345;
  struct Rng {
    uint32_t& s;
    uint8_t byte() {
      s = s * 1664525u + 1013904223u;
      return static_cast<uint8_t>(s >> 24);
    }
  } rng{seed};
  for (int round = 0; round < 3000; ++round) {
    uint8_t protocol = static_cast<uint8_t>(1 + (round & 1));
    uint8_t id = static_cast<uint8_t>(rng.byte() % 200);
    uint8_t body[9];
    size_t n = 1 + rng.byte() % 9;  // ERR + 0..8 parameters
    for (size_t i = 0; i < n; ++i) {
      uint8_t pick = rng.byte() % 4;
      body[i] = pick == 0 ? 0xFF : pick == 1 ? 0xFD : rng.byte();
    }
    body[0] &= 0x7F;  // an ERR byte
    uint8_t packet[40];
    size_t m = protocol == 1
                   ? dxl::build_packet(1, id, body[0], body + 1, n - 1, packet, sizeof packet)
                   : dxl::build_packet(2, id, dxl::kStatus, body, n, packet, sizeof packet);
    CHECK(m > 0, "round %d builds", round);
    dxl::StatusParser<8> parser(protocol);
    uint8_t noise = rng.byte() % 5;
    for (uint8_t i = 0; i < noise; ++i) parser.feed(protocol == 2 ? 0x00 : 0x13);
    bool done = false;
    for (size_t i = 0; i < m; ++i) done = parser.feed(packet[i]);
    CHECK(done && parser.id() == id, "round %d parsed (protocol %u)", round, protocol);
    CHECK(parser.error() == body[0] && parser.size() == n - 1, "round %d fields", round);
    CHECK(memcmp(parser.params(), body + 1, n - 1) == 0, "round %d params", round);
  }
  for (uint8_t protocol = 1; protocol <= 2; ++protocol) {
    struct Guarded {
      uint32_t before = 0xA5A5A5A5u;
      dxl::StatusParser<4> parser;
      uint32_t after = 0x5A5A5A5Au;
    } g;
    g.parser.set_protocol(protocol);
    for (int i = 0; i < 200000; ++i) {
      uint8_t pick = rng.byte() % 8;
      uint8_t b = pick == 0 ? 0xFF : pick == 1 ? 0xFD : pick == 2 ? 0x00 : rng.byte();
      if (g.parser.feed(b)) CHECK(g.parser.size() <= 4, "at most 4 parameters");
    }
    CHECK(g.before == 0xA5A5A5A5u && g.after == 0x5A5A5A5Au, "guards intact");
  }
}

int main() {
  test_quadrature();
  test_motors();
  test_sonar();
  test_mpu();
  test_dynamixel();
  test_dynamixel_parser_random();
  fprintf(stderr, "drivers: %lu checks passed\n", check::count());
  return 0;
}
