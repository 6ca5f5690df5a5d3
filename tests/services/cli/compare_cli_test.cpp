// Runs the real `pbgi compare` binary, as a user or a script would.

#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "formats/image/image_io.h"
#include "tests/support/run_pbgi.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

using testing::RunResult;
using testing::slurpFile;

using testing::runPbgi;

std::string quote(const std::string& s) { return testing::shellQuote(s); }

class CompareCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(fs::exists(testing::pbgiBinary())) << testing::pbgiBinary();
    dir_ = testing::makeTempDir("compare-cli");
    Image ref(4, 4, {"R", "G", "B"});
    Image img(4, 4, {"R", "G", "B"});
    for (int y = 0; y < 4; ++y)
      for (int x = 0; x < 4; ++x)
        for (int c = 0; c < 3; ++c) {
          ref.at(x, y, c) = 0.5f;
          img.at(x, y, c) = 0.75f;  // off by 0.25 everywhere: RMSE 0.25, PSNR 12.04 dB
        }
    image_ = (dir_ / "image.exr").string();
    reference_ = (dir_ / "reference.exr").string();
    ASSERT_TRUE(writeExr(img, image_).ok());
    ASSERT_TRUE(writeExr(ref, reference_).ok());
  }

  fs::path dir_;
  std::string image_;
  std::string reference_;
};

TEST_F(CompareCliTest, PrintsTheMetricsTable) {
  const RunResult r = runPbgi("compare " + quote(image_) + " " + quote(reference_));
  EXPECT_EQ(r.exitCode, 0) << r.err;
  EXPECT_NE(r.out.find("RMSE"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("relMSE"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("PSNR"), std::string::npos) << r.out;
  // The RGB row: means 0.75 and 0.5, RMSE 0.25, relMSE 0.0625/0.26, PSNR 20 log10(4).
  EXPECT_NE(r.out.find("RGB"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("0.240385"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("12.04"), std::string::npos) << r.out;
  EXPECT_TRUE(r.err.empty()) << r.err;
}

TEST_F(CompareCliTest, JsonIsOneLineWithTheMetrics) {
  const fs::path diff = dir_ / "out" / "diff.exr";
  const RunResult r = runPbgi("compare " + quote(image_) + " " + quote(reference_) +
                                        " --json --diff " + quote(diff.string()));
  EXPECT_EQ(r.exitCode, 0) << r.err;
  ASSERT_FALSE(r.out.empty());
  EXPECT_EQ(r.out.find('\n'), r.out.size() - 1) << r.out;
  EXPECT_EQ(r.out.front(), '{');
  EXPECT_NE(r.out.find("\"rmse\":0.25,"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("\"psnr\":12.0411998"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("\"width\":4,\"height\":4"), std::string::npos) << r.out;

  const absl::StatusOr<Image> written = readImage(diff.string());
  ASSERT_TRUE(written.ok()) << written.status();
  EXPECT_EQ(written->at(3, 3, written->channelIndex("G")), 0.25f);
}

TEST_F(CompareCliTest, IdenticalImagesReportInfinitePsnr) {
  const RunResult r = runPbgi("compare --json " + quote(image_) + " " + quote(image_));
  EXPECT_EQ(r.exitCode, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j.at("rmse").get<double>(), 0.0) << r.out;
  EXPECT_TRUE(j.at("psnr").is_null()) << r.out;  // JSON has no infinity
  EXPECT_TRUE(j.at("channels").at("G").at("psnr").is_null()) << r.out;
}

TEST_F(CompareCliTest, MissingFileIsBadInput) {
  const std::string missing = (dir_ / "missing.exr").string();
  const RunResult r = runPbgi("compare " + quote(missing) + " " + quote(reference_));
  EXPECT_EQ(r.exitCode, 2);
  EXPECT_EQ(r.err.rfind("pbgi: error: " + missing + ": ", 0), 0u) << r.err;
  EXPECT_TRUE(r.out.empty()) << r.out;
}

TEST_F(CompareCliTest, UnreadableFileIsBadInput) {
  const std::string garbage = (dir_ / "garbage.exr").string();
  std::ofstream(garbage) << "not an image\n";
  const RunResult r = runPbgi("compare " + quote(image_) + " " + quote(garbage));
  EXPECT_EQ(r.exitCode, 2);
  EXPECT_EQ(r.err.rfind("pbgi: error: " + garbage + ": ", 0), 0u) << r.err;
}

TEST_F(CompareCliTest, SizeMismatchIsBadInput) {
  const std::string small = (dir_ / "small.exr").string();
  ASSERT_TRUE(writeExr(Image(2, 3, {"R", "G", "B"}), small).ok());
  const RunResult r = runPbgi("compare " + quote(image_) + " " + quote(small));
  EXPECT_EQ(r.exitCode, 2);
  EXPECT_NE(r.err.find("4x4"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("2x3"), std::string::npos) << r.err;
}

TEST_F(CompareCliTest, MissingArgumentIsBadUsage) {
  const RunResult r = runPbgi("compare " + quote(image_));
  EXPECT_EQ(r.exitCode, 2);
  EXPECT_EQ(r.err.rfind("pbgi: error: ", 0), 0u) << r.err;
}

}  // namespace
}  // namespace pbgi
