// Host builds: a software UART that goes nowhere (as HardwareSerial here). See Arduino.h here.
#ifndef HWBRIDGE_HOST_SOFTWARESERIAL_H
#define HWBRIDGE_HOST_SOFTWARESERIAL_H

#include "Arduino.h"

class SoftwareSerial : public HardwareSerial {
 public:
  SoftwareSerial(uint8_t, uint8_t, bool = false) {}
  bool listen() { return true; }
  bool isListening() { return true; }
};

#endif  // HWBRIDGE_HOST_SOFTWARESERIAL_H
