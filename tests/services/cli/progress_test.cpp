#include "services/cli/progress.h"

#include <gtest/gtest.h>

namespace pbgi::cli {
namespace {

// The time left at the rate so far, rounded up, in the largest units that fit; nothing before
// a second of work or a first item done, or once everything is.
TEST(Progress, TimeLeftGoesByTheRateSoFar) {
  EXPECT_EQ(Progress::timeLeft(10.0, 50, 100), "10 s left");
  EXPECT_EQ(Progress::timeLeft(2.0, 1, 3), "4 s left");
  EXPECT_EQ(Progress::timeLeft(90.0, 10, 100), "13 min 30 s left");
  EXPECT_EQ(Progress::timeLeft(3600.0, 1, 4), "3 h 0 min left");
  EXPECT_EQ(Progress::timeLeft(0.5, 50, 100), "");
  EXPECT_EQ(Progress::timeLeft(10.0, 0, 100), "");
  EXPECT_EQ(Progress::timeLeft(10.0, 100, 100), "");
}

}  // namespace
}  // namespace pbgi::cli
