// Host time on an ARM board (tests/arm/test_examples.py): the node (ComfortableProfile: time
// requests of its own) asks the host for its time once connected, then publishes the host time
// it computes from its own clock on `host_time` ("SEC.MSEC") twice a second.
#include <HwBridge.h>
#include <std_msgs/String.h>

#if defined(HWBRIDGE_BOARD_STM32F4)
typedef hwbridge::Stm32f4Hardware BoardHardware;
#else
typedef hwbridge::Nrf51Hardware BoardHardware;
#endif

hwbridge::NodeHandle_<BoardHardware, hwbridge::ComfortableProfile> nh;
std_msgs::String text;
hwbridge::Publisher<std_msgs::String> host_time("host_time");
unsigned long last_ms = 0;

void setup() {
  nh.initNode(115200, "arm_time");
  nh.advertise(host_time);
}

void loop() {
  if (nh.connected() && millis() - last_ms >= 500) {
    last_ms = millis();
    if (!nh.timeSynced()) {
      nh.requestSyncTime();
    } else {
      uint32_t sec = 0, nsec = 0;
      nh.now(&sec, &nsec);
      char line[32];
      snprintf(line, sizeof line, "%lu.%03lu", static_cast<unsigned long>(sec),
               static_cast<unsigned long>(nsec / 1000000UL));
      text.data.assign(line);
      host_time.publish(text);
    }
  }
  nh.spinOnce();
}
