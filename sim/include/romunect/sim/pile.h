// A random pile in the bin: objects dropped one by one from seeded random poses, settled by
// physics until their kinetic energy stays below a threshold, and saved so the settled scene
// reloads exactly (the same doubles). Frames: W world, O object; SI units.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "romunect/sim/objects.h"
#include "romunect/sim/world.h"

namespace romunect::sim {

struct PileOptions {
  int num_objects = 10;
  std::vector<ObjectKind> kinds;  // drawn from these (seeded); empty: the five generated kinds
  uint32_t seed = 1;
  double drop_interval_s = 0.12;  // one object after the other, so none lands inside another
  double drop_height_m = 0.02;    // above the bin's rim
  // One layer (the paper's bins): every object lies on its broadest face (its bounding box's
  // thinnest axis up), about square to the walls (seeded: within 3 deg, either side up), dropped
  // from 2 mm above the bin floor at the free spot nearest the walls, its footprint (bounding
  // box) one_layer_gap_m from the walls and from the objects placed before it. An object that
  // finds no free spot is dropped onto the others as without one_layer, and counted.
  bool one_layer = false;
  double one_layer_gap_m = 0.001;
  // Physics time step while settling (the scene's own is restored afterwards): millimetre
  // parts falling at 1 m/s need sub-millimetre steps not to sink into each other.
  double timestep_s = 0.001;
  // Objects fall no faster than this while settling (a damper on the drop, not physics): MuJoCo's
  // soft contacts let a body sink about speed x contact time constant, so faster centimetre-sized
  // parts sink into the floor and get thrown out of the bin.
  double max_drop_speed_m_s = 0.3;
  double kinetic_energy_threshold_j = 2e-6;  // settled when the pile's energy stays below this
  double quiet_time_s = 0.1;                 // ... for this long
  double max_settle_time_s = 6.0;            // after the last drop; longer: not converged

  std::string Problem() const;  // "" when valid; otherwise "field = value: rule"
};

// The pile's objects (kinds and per-object seeds drawn from options.seed).
std::vector<ObjectSpec> MakePileObjects(const PileOptions& options);

struct SettleSummary {
  bool converged = false;
  double simulated_s = 0.0;  // physics time from the first drop to settled (or giving up)
  double kinetic_energy_j = 0.0;
  int objects_in_bin = 0;   // objects whose centre lies inside the bin's inner box
  int not_in_one_layer = 0;  // PileOptions::one_layer: objects that found no free spot on the floor
  double wall_s = 0.0;      // wall-clock time spent
  std::string loaded_from;  // a SaveSettledScene() file the pile came from: nothing settled

  std::string BriefReport() const;
};

// Drops all of the world's objects into its bin (poses from options.seed) and steps the
// physics until settled. The arm keeps its pose. Never throws: a settle that does not converge
// comes back with converged = false (callers turn that into an error for the user).
SettleSummary DropAndSettle(World* world, const PileOptions& options);

// Whether an object's origin lies over the bin's inner floor, at most 30 mm above the rim.
bool ObjectInBin(const World& world, int object);

// A settled scene on disk (JSON, "romunect-scene" version 1): the scene file, the rig, the
// objects (generated ones by kind and seed, user meshes by file) and every object's pose as
// doubles printed for an exact round trip (qpos: x y z then quaternion w x y z).
void SaveSettledScene(const World& world, const std::filesystem::path& path);
// Rebuilds the world of a saved scene with the objects at their saved poses, bit for bit.
// Throws InputError naming the file and the field on anything wrong.
World LoadSettledScene(const std::filesystem::path& path);

}  // namespace romunect::sim
