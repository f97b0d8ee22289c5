// Blink: a subscriber. Each std_msgs/Empty on `toggle_led` toggles the built-in LED; a
// std_msgs/Bool on `led` sets it.
//
//   hwbridge topic pub -1 /toggle_led std_msgs/Empty '{}'
//   hwbridge topic pub -1 /led std_msgs/Bool '{data: true}'
#include <HwBridge.h>
#include <std_msgs/Bool.h>
#include <std_msgs/Empty.h>

hwbridge::NodeHandle nh;

void on_toggle(const std_msgs::Empty&) {
  digitalWrite(LED_BUILTIN, !digitalRead(LED_BUILTIN));
}

void on_led(const std_msgs::Bool& msg) {
  digitalWrite(LED_BUILTIN, msg.data ? HIGH : LOW);
}

hwbridge::Subscriber<std_msgs::Empty> toggle_sub("toggle_led", &on_toggle);
hwbridge::Subscriber<std_msgs::Bool> led_sub("led", &on_led);

void setup() {
  pinMode(LED_BUILTIN, OUTPUT);
  nh.initNode(115200, "blink");
  nh.subscribe(toggle_sub);
  nh.subscribe(led_sub);
}

void loop() {
  nh.spinOnce();
}
