// `pbgi run`, the embedded farm, as users run it: the real binary starting real pbgi-worker
// processes. Its frames must be the frames `pbgi render` makes, bit for bit.

#include <gtest/gtest.h>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "formats/image/image_io.h"
#include "tests/support/farm_fixtures.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;
using testing::runPbgi;
using testing::shellQuote;

TEST(RunCliTest, TwoFramesOnTwoWorkersEqualPbgiRender) {
  const fs::path dir = testing::makeTempDir("run-cli");
  testing::SmallShot small;
  small.spp = 3;
  const fs::path shot = testing::writeSmallShot(dir, small);
  const testing::RunResult run = runPbgi("run " + shellQuote(shot.string()) +
                                         " --workers 2 --tile-size 32 --state " +
                                         shellQuote((dir / "state").string()));
  ASSERT_EQ(run.exitCode, 0) << run.output();
  EXPECT_NE(run.output().find("submitted job 1"), std::string::npos) << run.output();
  for (int frame : {1, 2}) {
    const fs::path farmFrame = dir / fmt::format("out/small.{:04d}.exr", frame);
    EXPECT_NE(run.output().find("wrote " + farmFrame.string()), std::string::npos) << run.output();
    EXPECT_TRUE(fs::exists(dir / fmt::format("out/small.{:04d}.png", frame)));
    const fs::path alone = dir / fmt::format("alone.{}.exr", frame);
    const testing::RunResult render =
        runPbgi(fmt::format("render {} --frame {} --no-preview --out {}", shellQuote(shot.string()),
                            frame, shellQuote(alone.string())));
    ASSERT_EQ(render.exitCode, 0) << render.output();
    auto a = readImage(farmFrame.string());
    auto b = readImage(alone.string());
    ASSERT_TRUE(a.ok() && b.ok()) << a.status() << b.status();
    std::string why;
    EXPECT_TRUE(testing::samePixels(*a, *b, &why)) << "frame " << frame << ": " << why;
  }
  // Both workers registered and logged their tasks.
  EXPECT_TRUE(fs::exists(dir / "state/jobs/1/worker-0.log"));
  EXPECT_TRUE(fs::exists(dir / "state/jobs/1/worker-1.log"));
  // A second run of a finished job submits a new one rather than resuming.
  const testing::RunResult again = runPbgi("run " + shellQuote(shot.string()) +
                                           " --frames 2 --tile-size 32 --state " +
                                           shellQuote((dir / "state").string()));
  ASSERT_EQ(again.exitCode, 0) << again.output();
  EXPECT_NE(again.output().find("submitted job 2"), std::string::npos) << again.output();
  fs::remove_all(dir);
}

// The image flags travel with the job, typed: the farm's frame is `pbgi render`'s with the
// same flags, bit for bit, and --json prints the finished job as status --json does.
TEST(RunCliTest, ResolutionSeedAovsAndCompressionReachTheFarmsFrame) {
  const fs::path dir = testing::makeTempDir("run-cli-image");
  testing::SmallShot small;
  small.lastFrame = 1;
  const fs::path shot = testing::writeSmallShot(dir, small);
  const std::string flags = " --scale 0.75 --seed 99 --aovs depth --exr-compression piz";
  const testing::RunResult run =
      runPbgi("run " + shellQuote(shot.string()) + flags + " --tile-size 16 --json --state " +
              shellQuote((dir / "state").string()));
  ASSERT_EQ(run.exitCode, 0) << run.output();
  const auto json = nlohmann::json::parse(run.out);
  EXPECT_EQ(json["state"], "done") << run.out;
  EXPECT_EQ(json["job"], 1) << run.out;
  const fs::path farmFrame = dir / "out/small.0001.exr";
  const fs::path alone = dir / "alone.exr";
  const testing::RunResult render = runPbgi("render " + shellQuote(shot.string()) + flags +
                                            " --no-preview --out " + shellQuote(alone.string()));
  ASSERT_EQ(render.exitCode, 0) << render.output();
  auto a = readImage(farmFrame.string());
  auto b = readImage(alone.string());
  ASSERT_TRUE(a.ok() && b.ok()) << a.status() << b.status();
  EXPECT_EQ(a->width(), 48);
  EXPECT_EQ(a->channels(), (std::vector<std::string>{"R", "G", "B", "A", "depth.Z"}));
  std::string why;
  EXPECT_TRUE(testing::samePixels(*a, *b, &why)) << why;
  // Another seed, other pixels: the seed reached the workers.
  const testing::RunResult other = runPbgi("render " + shellQuote(shot.string()) +
                                           " --scale 0.75 --seed 98 --no-preview --out " +
                                           shellQuote((dir / "other.exr").string()));
  ASSERT_EQ(other.exitCode, 0) << other.output();
  auto c = readImage((dir / "other.exr").string());
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_NE(c->pixels()[0], a->pixels()[0]);
  fs::remove_all(dir);
}

TEST(RunCliTest, AnInterruptedRunResumesItsJob) {
  const fs::path dir = testing::makeTempDir("run-cli-resume");
  testing::SmallShot slow;
  slow.spp = 256;
  const fs::path shot = testing::writeSmallShot(dir, slow);
  const std::string state = (dir / "state").string();
  testing::Process first({testing::pbgiBinary().string(), "run", shot.string(), "--tile-size",
                          "32", "--threads", "1", "--state", state},
                         dir / "first.log");
  // Interrupted once a tile is done (each takes a fraction of a second on one thread).
  ASSERT_TRUE(testing::waitFor(
      [&] { return fs::exists(dir / "state/jobs/1/frame.0001/tile.0000.exr"); }, 60.0))
      << first.log();
  first.signal(SIGINT);
  EXPECT_EQ(first.wait(60.0), 1) << first.log();
  EXPECT_NE(first.log().find("run the same command again to resume job 1"), std::string::npos)
      << first.log();
  EXPECT_FALSE(fs::exists(dir / "out/small.0002.exr"));
  const testing::RunResult second = runPbgi("run " + shellQuote(shot.string()) +
                                            " --tile-size 32 --state " + shellQuote(state));
  ASSERT_EQ(second.exitCode, 0) << second.output();
  EXPECT_NE(second.output().find("resuming job 1"), std::string::npos) << second.output();
  const fs::path alone = dir / "alone.exr";
  ASSERT_EQ(runPbgi("render " + shellQuote(shot.string()) + " --frame 2 --no-preview --out " +
                    shellQuote(alone.string()))
                .exitCode,
            0);
  auto a = readImage((dir / "out/small.0002.exr").string());
  auto b = readImage(alone.string());
  ASSERT_TRUE(a.ok() && b.ok());
  std::string why;
  EXPECT_TRUE(testing::samePixels(*a, *b, &why)) << why;
  fs::remove_all(dir);
}

// A camera array renders whole through the farm: farm tiles carry a rectangle of every view,
// the views of a tile share one bidirectional cut, and the assembled mosaic is the one `pbgi
// render` makes, bit for bit (before, the farm wrote view 0 alone).
TEST(RunCliTest, ACameraArrayThroughTheFarmEqualsPbgiRender) {
  const fs::path dir = testing::makeTempDir("run-cli-views");
  testing::SmallShot views;
  views.width = 40;
  views.height = 32;
  views.lastFrame = 1;
  views.spp = 2;
  views.integrator = "pbgi";
  views.extraRender = "bake_points = 20000\nbake_bounces = 1\ncut_block = 16\n";
  views.extraCamera = "views = [2, 2]\nview_spacing = 30.0\n";
  const fs::path shot = testing::writeSmallShot(dir, views);
  const testing::RunResult run = runPbgi("run " + shellQuote(shot.string()) +
                                         " --workers 2 --tile-size 24 --state " +
                                         shellQuote((dir / "state").string()));
  ASSERT_EQ(run.exitCode, 0) << run.output();
  const fs::path alone = dir / "alone.exr";
  const testing::RunResult render = runPbgi("render " + shellQuote(shot.string()) +
                                            " --no-preview --out " + shellQuote(alone.string()));
  ASSERT_EQ(render.exitCode, 0) << render.output();
  auto a = readImage((dir / "out/small.0001.exr").string());
  auto b = readImage(alone.string());
  ASSERT_TRUE(a.ok() && b.ok()) << a.status() << b.status();
  EXPECT_EQ(a->width(), 80);
  EXPECT_EQ(a->height(), 64);
  std::string why;
  EXPECT_TRUE(testing::samePixels(*a, *b, &why)) << why;
  // Every view was rendered: no quadrant of the mosaic is black.
  for (int view = 0; view < 4; ++view) {
    double sum = 0.0;
    for (int y = 0; y < 32; ++y) {
      for (int x = 0; x < 40; ++x) sum += a->at((view % 2) * 40 + x, (view / 2) * 32 + y, 0);
    }
    EXPECT_GT(sum, 0.0) << "view " << view;
  }
  fs::remove_all(dir);
}

TEST(RunCliTest, BadShotsAndFlagsExitTwoBeforeAnythingStarts) {
  const fs::path dir = testing::makeTempDir("run-cli-bad");
  const fs::path shot = dir / "bad.toml";
  std::ofstream(shot) << "version = 1\n[shot]\nname = \"x\"\nbogus = 3\n";
  const testing::RunResult bad = runPbgi("run " + shellQuote(shot.string()));
  EXPECT_EQ(bad.exitCode, 2) << bad.output();
  EXPECT_NE(bad.output().find("bad.toml:"), std::string::npos) << bad.output();
  const fs::path good = testing::writeSmallShot(dir, {});
  const testing::RunResult frames = runPbgi("run " + shellQuote(good.string()) + " --frames 1-x");
  EXPECT_EQ(frames.exitCode, 2) << frames.output();
  EXPECT_NE(frames.output().find("--frames 1-x"), std::string::npos) << frames.output();
  const testing::RunResult outside = runPbgi("run " + shellQuote(good.string()) + " --frames 5");
  EXPECT_EQ(outside.exitCode, 2) << outside.output();
  EXPECT_FALSE(fs::exists(dir / "out"));
  fs::remove_all(dir);
}

}  // namespace
}  // namespace pbgi
