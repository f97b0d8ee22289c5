// CanNode: a board on a CAN bus through an MCP2515 module on SPI (CS on pin 10). It is CAN node
// 5: it publishes the reading of A0 (std_msgs/UInt16 on `a0`, 10 a second) and sets the
// brightness of an LED on pin 5 from `brightness` (std_msgs/UInt8). Pin 13 is the SPI clock on
// an Uno, so the built-in LED is not used.
//
//   hwbridge connect can://slcan/dev/ttyACM0/node5?bitrate=500000   # a USB-CAN adapter
//   hwbridge topic echo /a0
//   hwbridge topic pub -1 /brightness std_msgs/UInt8 '{data: 128}'
//
// Set CAN_CRYSTAL to your module's crystal (many have 8 MHz) and CAN_BITRATE to the bus's.
#include <HwBridge.h>
#include <SPI.h>
#include <hwbridge/can/can_hardware.h>
#include <hwbridge/can/mcp2515.h>
#include <std_msgs/UInt16.h>
#include <std_msgs/UInt8.h>

#define CAN_NODE 5
#define CAN_CS_PIN 10
#define CAN_CRYSTAL 16000000UL
#define CAN_BITRATE 500000UL
#define LED_PIN 5

hwbridge::NodeHandle_<hwbridge::can::CanHardware<hwbridge::can::Mcp2515> > nh;
std_msgs::UInt16 a0_msg;
hwbridge::Publisher<std_msgs::UInt16> a0_pub("a0");

void on_brightness(const std_msgs::UInt8& msg) { analogWrite(LED_PIN, msg.data); }
hwbridge::Subscriber<std_msgs::UInt8> brightness_sub("brightness", &on_brightness);

unsigned long last_ms = 0;

void setup() {
  pinMode(LED_PIN, OUTPUT);
  nh.getHardware().setNode(CAN_NODE);
  nh.getHardware().driver().port().setPin(CAN_CS_PIN);
  nh.getHardware().driver().configure(CAN_BITRATE, CAN_CRYSTAL);
  nh.initNode(0, "cannode");
  nh.advertise(a0_pub);
  nh.subscribe(brightness_sub);
}

void loop() {
  if (millis() - last_ms >= 100) {
    last_ms = millis();
    a0_msg.data = analogRead(A0);
    a0_pub.publish(a0_msg);
  }
  nh.spinOnce();
}
