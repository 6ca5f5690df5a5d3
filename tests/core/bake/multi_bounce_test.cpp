#include "core/bake/multi_bounce.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>

namespace pbgi {
namespace {

// The light past the last bounce against the series it stands for, the scene's ratio in the
// limit a = 0.6 (tail factor 1.5): a surface's light of the scene's mode and one of its own,
// A a^k + C q^k, is summed exactly from its last three bounces, whichever way it goes.
TEST(MultiBounce, TheTailFollowsEachSurfacesOwnLight) {
  const double a = 0.6;
  const Rgb f(static_cast<float>(a / (1.0 - a)));
  struct Series {
    const char* name;
    std::function<double(int)> light;  // dE_k
    double geometricAtMost;            // of the exact tail, for the scene's geometric one alone
  };
  const Series series[] = {
      {"falls at the scene's rate", [&](int k) { return std::pow(a, k); }, 1.0},
      // A room lit through a door from a room like it: k a^(k-1), still rising at bounce 2.
      {"a room lit from a room like it", [&](int k) { return k * std::pow(a, k - 1); }, 0.8},
      // ... from a room that passes light on faster than it does (0.3 against 0.6).
      {"a room lit from a darker one",
       [&](int k) { return (std::pow(a, k) - std::pow(0.3, k)) / (a - 0.3); }, 0.99},
      // A surface lit directly, whose own light dies out first: less than the geometric tail.
      {"lit directly", [&](int k) { return std::pow(0.3, k) + 0.1 * std::pow(a, k); }, 2.0},
  };
  for (const Series& s : series) {
    for (const int bounces : {3, 4, 6}) {
      SCOPED_TRACE(::testing::Message() << s.name << ", " << bounces << " bounces");
      double exact = 0.0;
      for (int k = bounces + 1; k < 400; ++k) exact += s.light(k);
      const auto at = [&](int k) { return Rgb(static_cast<float>(s.light(k))); };
      const Rgb local = tailLight(at(bounces), at(bounces - 1), at(bounces - 2), f, true);
      EXPECT_NEAR(local.x, exact, 2e-4 * exact);
      const Rgb geometric = tailLight(at(bounces), at(bounces - 1), at(bounces - 2), f, false);
      EXPECT_FLOAT_EQ(geometric.x, at(bounces).x * f.x);
      EXPECT_LE(geometric.x, s.geometricAtMost * exact * 1.0001);
    }
  }
  // Bounces that swing (light passed back and forth) are no such series: the geometric tail.
  EXPECT_FLOAT_EQ(tailLight(Rgb(1.0f), Rgb(0.2f), Rgb(1.0f), f, true).x, f.x);
  // No tail factor, no tail.
  EXPECT_EQ(tailLight(Rgb(1.0f), Rgb(0.5f), Rgb(0.2f), Rgb(0.0f), true), Rgb(0.0f));
}

}  // namespace
}  // namespace pbgi
