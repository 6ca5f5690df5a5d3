#include "services/coordinator/coordinator.h"

int main(int argc, char** argv) { return pbgi::farm::coordinatorDaemonMain(argc, argv); }
