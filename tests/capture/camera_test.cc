#include "capture/camera.h"

#include <limits>

#include <gtest/gtest.h>

#include "core/error.h"

namespace slshadow::capture {
namespace {

TEST(CameraSettings, EnumNamesRoundTrip) {
  for (PixelFormat f : {PixelFormat::kMono8, PixelFormat::kMono12, PixelFormat::kMono16}) {
    EXPECT_EQ(PixelFormatFromString(ToString(f)), f);
  }
  for (TriggerMode m : {TriggerMode::kFreeRun, TriggerMode::kSoftware, TriggerMode::kHardware}) {
    EXPECT_EQ(TriggerModeFromString(ToString(m)), m);
  }
  EXPECT_EQ(BitDepthOf(PixelFormat::kMono8), 8);
  EXPECT_EQ(BitDepthOf(PixelFormat::kMono12), 16);
  EXPECT_THROW(PixelFormatFromString("RGB8"), Error);
  EXPECT_THROW(TriggerModeFromString("line"), Error);
}

TEST(CameraSettings, CheckNamesTheBadField) {
  CameraSettings s;
  s.Check("left");
  s.exposure_us = -5;
  try {
    s.Check("left");
    FAIL() << "negative exposure accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("left: exposure_us"), std::string::npos) << e.what();
  }
  s.exposure_us = 1000;
  s.roi = {0, 0, 640, 0};
  EXPECT_THROW(s.Check("left"), Error);
  s.roi = {};
  s.gain_db = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(s.Check("left"), Error);
}

}  // namespace
}  // namespace slshadow::capture
