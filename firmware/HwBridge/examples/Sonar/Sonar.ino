// Sonar: an HC-SR04 ranger, paired with the `hcsr04` device plugin. Publishes each echo width
// (hwbridge_msgs/SonarEcho) on `sonar_echo`; the host node turns it into sensor_msgs/Range on
// `range`. Trigger on pin 9, Echo on pin 3 (an interrupt pin: the echo is timed exactly; on a
// pin without one it is polled at each loop()). 15 measurements a second.
//
//   robot file:  - type: hcsr04
//                  rate: 15
//   hwbridge topic echo /range
#include <HwBridge.h>
#include <hwbridge/drivers/hcsr04.h>
#include <hwbridge_msgs/SonarEcho.h>

const float kTemperatureC = 20.0f;  // air temperature, for the speed of sound

hwbridge::NodeHandle nh;
hwbridge::drivers::HcSr04<9, 3> sonar;
hwbridge_msgs::SonarEcho echo_msg;
hwbridge::Publisher<hwbridge_msgs::SonarEcho> echo_pub("sonar_echo");

void setup() {
  nh.initNode(115200, "sonar");
  nh.advertise(echo_pub);
  echo_msg.header.frame_id.assign("sonar_link");
  sonar.begin(66);
}

void loop() {
  if (sonar.update()) {
    sonar.fill(echo_msg, kTemperatureC);
    nh.now(&echo_msg.header.stamp.sec, &echo_msg.header.stamp.nsec);
    ++echo_msg.header.seq;
    echo_pub.publish(echo_msg);
  }
  nh.spinOnce();
}
