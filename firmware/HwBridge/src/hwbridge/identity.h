// The firmware identity a board sends in BOARD_INFO after its version text (PROTOCOL.md
// 2.6.1): one string literal, joined at compile time and kept in flash on AVR.
//
// A sketch names itself by defining, before #include <HwBridge.h>:
//   #define HWBRIDGE_FIRMWARE_NAME "diffbot/base"                // what it calls itself
//   #define HWBRIDGE_BUILD_TAG "diffbot/base@0123456789ab"       // `hwbridge firmware generate`
// The schema and message-definition hashes come from the generated headers
// (hwbridge_control.h, hwbridge_msgdefs.h), the version from HWBRIDGE_LIBRARY_VERSION.
#ifndef HWBRIDGE_IDENTITY_H
#define HWBRIDGE_IDENTITY_H

#include "progmem.h"
#include "../hwbridge_control.h"
#include "../hwbridge_msgdefs.h"

/** The HwBridge library's version (library.properties; a test keeps the two equal). */
#ifndef HWBRIDGE_LIBRARY_VERSION
#define HWBRIDGE_LIBRARY_VERSION "0.1.0"
#endif

#define HWBRIDGE_ID_ITEM_(key, value) "\n" key "=" value

// One macro per item of HWBRIDGE_ID_ITEMS_ (hwbridge_control.h, in the schema's order).
#define HWBRIDGE_ID_SCHEMA_HASH_ HWBRIDGE_ID_ITEM_(HWBRIDGE_ID_KEY_SCHEMA_HASH, HWBRIDGE_SCHEMA_HASH)
#define HWBRIDGE_ID_MESSAGES_HASH_ \
  HWBRIDGE_ID_ITEM_(HWBRIDGE_ID_KEY_MESSAGES_HASH, HWBRIDGE_MSGS_HASH)
#define HWBRIDGE_ID_LIBRARY_VERSION_ \
  HWBRIDGE_ID_ITEM_(HWBRIDGE_ID_KEY_LIBRARY_VERSION, HWBRIDGE_LIBRARY_VERSION)
#ifdef HWBRIDGE_BUILD_TAG
#define HWBRIDGE_ID_BUILD_TAG_ HWBRIDGE_ID_ITEM_(HWBRIDGE_ID_KEY_BUILD_TAG, HWBRIDGE_BUILD_TAG)
#else
#define HWBRIDGE_ID_BUILD_TAG_ ""
#endif
#ifdef HWBRIDGE_FIRMWARE_NAME
#define HWBRIDGE_ID_NAME_ HWBRIDGE_ID_ITEM_(HWBRIDGE_ID_KEY_NAME, HWBRIDGE_FIRMWARE_NAME)
#else
#define HWBRIDGE_ID_NAME_ ""
#endif

namespace hwbridge {
namespace detail {

/** The identity items, each "\n" key "=" value, and the final "\n" (a send buffer too small for
 * all of them cuts the last ones: the schema puts the most useful first). A template so that its
 * one definition may sit in a header. */
template <class D = void>
struct Identity {
  static const char text[];
};
template <class D>
const char Identity<D>::text[] HWBRIDGE_PROGMEM = HWBRIDGE_ID_ITEMS_ "\n";

}  // namespace detail
}  // namespace hwbridge

#endif  // HWBRIDGE_IDENTITY_H
