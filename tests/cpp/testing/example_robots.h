// Robots of the example-robot-data package that the C++ tests build their stacks on.
#pragma once

#include <string>

#include "marionette/sot/kinematics.h"

namespace marionette::sot {

/// TALOS (talos_reduced.urdf, free-flyer, 38 DoF) with its SRDF reference configurations.
inline ModelPtr LoadTalos() {
  const std::string dir = ExampleRobotDataDir() + "/talos_data/";
  return LoadModel(dir + "robots/talos_reduced.urdf", BaseJoint::kFreeFlyer,
                   dir + "srdf/talos.srdf");
}

}  // namespace marionette::sot
