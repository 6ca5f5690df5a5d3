#include "services/worker/worker.h"

int main(int argc, char** argv) { return pbgi::farm::workerDaemonMain(argc, argv); }
