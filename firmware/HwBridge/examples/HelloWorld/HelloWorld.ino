// HelloWorld: the smallest hwbridge node. Publishes "hello world!" on `chatter` once a second.
//
//   hwbridge connect /dev/ttyACM0             # on the host (the board at 115200 baud)
//   hwbridge topic echo /chatter
#include <HwBridge.h>
#include <std_msgs/String.h>

hwbridge::NodeHandle nh;
std_msgs::String str_msg;
hwbridge::Publisher<std_msgs::String> chatter("chatter");

unsigned long last_ms = 0;

void setup() {
  nh.initNode(115200, "hello");
  nh.advertise(chatter);
  str_msg.data.assign("hello world!");
}

void loop() {
  // Publish without delay(): spinOnce() must run often to keep the link alive.
  if (millis() - last_ms >= 1000) {
    last_ms = millis();
    chatter.publish(str_msg);
  }
  nh.spinOnce();
}
