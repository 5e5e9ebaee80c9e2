#pragma once
/// The automatic hold controller: what the loop swaps in when an entity
/// of the running controller overruns its compute-time budget too many ticks in a row.
///
///   walking humanoid   [its balance tasks: the walk's feet and CoM, the waist...] > [posture
///                      held]: the running walk is
///                      adopted and ends with the step in progress (FootstepManager::
///                      StopAfterCurrentStep), then stands, the ZMP in the middle of the feet
///   standing humanoid  [both soles held where they are, CoM over the support] > [posture held]
///   arm                [posture held]
///
/// Why a walking robot finishes its step: mid-step its CoM is on its way to the next support
/// foot, accelerated by gravity about the ZMP under the stance foot (Dang 2012 §2.4, eq. 2.47);
/// its capture point is past the stance foot's edge, so no motion on that foot stops it — measured
/// by hand on the bundled humanoid in MuJoCo: with its joints frozen it fell, with its feet and CoM
/// held (with or without the waist) it fell within 1.5 s. Landing the swing foot where the plan put
/// it gives the support the CoM is heading for. Standing: "over the support" is the centre of the
/// soles on the ground (those within kSupportHeight of the lowest), at the CoM's current height.
///
/// It is a controller like any other: a spec built by the ControllerFactory off the loop against
/// the running controller, so the loop engages it with one Graph::Apply. Its references are the
/// walk's or "hold where it is" (set at the swap by BuiltController::HoldCurrent), so what it
/// does depends only on the tick it is engaged at: a replay reproduces it.

#include <memory>
#include <string>
#include <vector>

#include "marionette/controller/controller_factory.h"
#include "marionette/lcmt_controller_spec.hpp"

namespace marionette::controller {

/// The id the hold controller reports as active (supervisors' ids are >= 0; -1 is "none").
inline constexpr int64_t kHoldControllerId = -2;
/// A sole is on the ground when it is at most this far above the lowest sole [m].
inline constexpr double kSupportHeight = 0.01;

/// The hold controller's spec for a robot whose contact soles are `soles` (empty: an arm), or,
/// for a walking controller, its `balance_tasks` (BuiltController::balance_tasks) + posture.
lcmt_controller_spec HoldControllerSpec(const std::vector<std::string>& soles,
                                        const std::vector<lcmt_task_spec>& balance_tasks = {});

/// Builds the hold controller of `running` (the active controller) with `factory` against `graph`
/// (`q`: a recent configuration, as ControllerFactory::Build) and adds what it does at the swap:
/// stop the walk after the step in progress, or move the CoM over the support. Throws like
/// ControllerFactory::Build (e.g. a sole frame the model lacks).
std::unique_ptr<BuiltController> BuildHoldController(
    const ControllerFactory& factory, const graph::Graph& graph, const BuiltController& running,
    const Eigen::VectorXd& q, const sot::ModelPtr& model, const std::vector<std::string>& soles);

}  // namespace marionette::controller
