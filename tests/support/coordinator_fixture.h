#pragma once
// An in-process coordinator on loopback (gRPC and HTTP on port 0) with a client that bears its
// token; the tests speak the workers' calls themselves, so each rule is exercised exactly.
#include <gtest/gtest.h>

#include <httplib.h>

#include <filesystem>
#include <memory>
#include <string>

#include "services/coordinator/coordinator.h"
#include "services/farm/farm_client.h"
#include "tests/support/farm_fixtures.h"

namespace pbgi::testing {

using farm::Coordinator;
using farm::CoordinatorOptions;
using farm::FarmClient;
namespace v1 = farm::v1;
namespace fs = std::filesystem;

class CoordinatorTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = makeTempDir("coordinator");
    options_.stateDir = (dir_ / "state").string();
    options_.outputRoot = (dir_ / "out-root").string();
    options_.token = "secret-token";
    options_.httpListen = "127.0.0.1:0";
    options_.tileSize = 32;
    options_.retry.backoffBase = 0.0;
    fs::create_directories(options_.outputRoot);
  }
  void TearDown() override {
    coordinator_.reset();
    fs::remove_all(dir_);
  }
  void start() {
    auto c = Coordinator::start(options_);
    ASSERT_TRUE(c.ok()) << c.status();
    coordinator_ = *std::move(c);
    client_ = std::make_unique<FarmClient>(coordinator_->address(), options_.token, 10.0);
  }
  v1::SubmitJobRequest shotRequest(const SmallShot& shot) {
    const fs::path path = writeSmallShot(fs::path(options_.outputRoot), shot);
    v1::SubmitJobRequest request;
    request.set_shot_path(path.string());
    request.set_shot_text(slurpFile(path));
    return request;
  }
  std::string metrics() {
    httplib::Client http("http://" + coordinator_->httpAddress());
    // The token as a scraper sends it: /metrics reads need it under --read-access token.
    auto res = http.Get("/metrics", {{"Authorization", "Bearer " + options_.token}});
    return res ? res->body : std::string();
  }

  fs::path dir_;
  CoordinatorOptions options_;
  std::unique_ptr<Coordinator> coordinator_;
  std::unique_ptr<FarmClient> client_;
};

}  // namespace pbgi::testing
