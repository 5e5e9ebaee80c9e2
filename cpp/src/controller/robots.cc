#include "marionette/controller/robots.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <stdexcept>

namespace marionette::controller {
namespace {

namespace fs = std::filesystem;
constexpr const char* kRobotFile = "robot.yaml";

[[noreturn]] void Fail(const std::string& where, const std::string& what) {
  throw std::invalid_argument(where + ": " + what);
}

// node[key] as T, with the file and the key's path in the error (yaml-cpp's own messages name
// neither).
template <typename T>
T Get(const YAML::Node& node, const std::string& key, const std::string& where) {
  const YAML::Node value = node[key];
  if (!value) Fail(where, key + " is missing (required)");
  try {
    return value.as<T>();
  } catch (const YAML::Exception&) {
    Fail(where, key + " has the wrong type (line " + std::to_string(value.Mark().line + 1) + ")");
  }
}

template <typename T>
T GetOr(const YAML::Node& node, const std::string& key, const std::string& where, T fallback) {
  return node[key] ? Get<T>(node, key, where) : fallback;
}

YAML::Node Sequence(const YAML::Node& node, const std::string& key, const std::string& where) {
  const YAML::Node value = node[key];
  if (value && !value.IsSequence()) Fail(where, key + " must be a list");
  return value;
}

RobotInfo Read(const fs::path& folder) {
  const fs::path file = folder / kRobotFile;
  const std::string where = file.string();
  YAML::Node doc;
  try {
    doc = YAML::LoadFile(where);
  } catch (const YAML::BadFile&) {
    Fail(where, "cannot read it");
  } catch (const YAML::ParserException& e) {
    Fail(where + ":" + std::to_string(e.mark.line + 1), "not valid YAML: " + e.msg);
  }
  if (!doc.IsMap()) Fail(where, "must be a mapping (see docs/robots.md)");
  const std::string format = Get<std::string>(doc, "format", where);
  if (format != "marionette-robot 1") {
    Fail(where, "format '" + format + "' is not 'marionette-robot 1'");
  }
  RobotInfo r;
  r.name = Get<std::string>(doc, "name", where);
  if (r.name != folder.filename().string()) {
    Fail(where, "name '" + r.name + "' differs from its folder '" + folder.filename().string() +
                    "'; rename one so that they agree");
  }
  r.directory = folder.string();
  r.urdf = (folder / Get<std::string>(doc, "urdf", where)).string();
  r.srdf = (folder / Get<std::string>(doc, "srdf", where)).string();
  r.mjcf = (folder / Get<std::string>(doc, "mjcf", where)).string();
  r.base = Get<std::string>(doc, "base", where);
  if (r.base != "free_flyer" && r.base != "planar" && r.base != "fixed") {
    Fail(where, "base '" + r.base + "' is not one of free_flyer, planar, fixed");
  }
  r.reference = Get<std::string>(doc, "reference_posture", where);
  if (const YAML::Node feet = Sequence(doc, "feet", where)) {
    for (size_t i = 0; i < feet.size(); ++i) {
      r.contact_bodies.push_back(
          Get<std::string>(feet[i], "frame", where + ": feet/" + std::to_string(i)));
    }
  }
  if (const YAML::Node cameras = Sequence(doc, "cameras", where); cameras && cameras.size() > 0) {
    r.camera = Get<std::string>(cameras[0], "name", where + ": cameras/0");
    r.camera_frame = Get<std::string>(cameras[0], "frame", where + ": cameras/0");
  }
  if (const YAML::Node grippers = Sequence(doc, "grippers", where)) {
    for (size_t i = 0; i < grippers.size(); ++i) {
      const YAML::Node g = grippers[i];
      const std::string at = where + ": grippers/" + std::to_string(i);
      for (const auto& jaw : GetOr<std::vector<std::vector<std::string>>>(g, "jaws", at, {})) {
        r.grip_bodies.insert(r.grip_bodies.end(), jaw.begin(), jaw.end());
      }
      if (!g["joint"]) continue;  // a tool tip or a suction cup: nothing to drive
      r.grippers.push_back({Get<std::string>(g, "name", at), Get<std::string>(g, "joint", at),
                            Get<double>(g, "open_position", at),
                            Get<double>(g, "closed_position", at)});
    }
  }
  return r;
}

// name -> folder of every robot on the search path (the first one found wins).
std::map<std::string, fs::path> Folders(const std::string& models_dir) {
  std::map<std::string, fs::path> out;
  for (const std::string& root : RobotSearchPath(models_dir)) {
    std::error_code ec;
    if (fs::is_regular_file(fs::path(root) / kRobotFile, ec)) {
      out.emplace(fs::path(root).filename().string(), fs::path(root));
      continue;
    }
    std::vector<fs::path> children;
    for (const auto& entry : fs::directory_iterator(root, ec)) {
      if (fs::is_regular_file(entry.path() / kRobotFile, ec)) children.push_back(entry.path());
    }
    std::sort(children.begin(), children.end());
    for (const fs::path& c : children) out.emplace(c.filename().string(), c);
  }
  return out;
}

}  // namespace

std::vector<std::string> RobotSearchPath(const std::string& models_dir) {
  std::vector<std::string> path{models_dir};
  if (const char* extra = std::getenv("MARIONETTE_ROBOT_PATH")) {
    std::string s(extra);
    for (size_t start = 0; start <= s.size();) {
      const size_t end = std::min(s.find(':', start), s.size());
      if (end > start) path.push_back(s.substr(start, end - start));
      start = end + 1;
    }
  }
  return path;
}

std::vector<std::string> RobotNames(const std::string& models_dir) {
  std::vector<std::string> names;
  for (const auto& [name, folder] : Folders(models_dir)) names.push_back(name);
  return names;
}

RobotInfo FindRobot(const std::string& name_or_folder, const std::string& models_dir) {
  std::error_code ec;
  fs::path given(name_or_folder);
  if (given.filename() == kRobotFile) given = given.parent_path();
  const bool is_path = name_or_folder.find('/') != std::string::npos;
  if (is_path || fs::is_regular_file(given / kRobotFile, ec)) {
    if (!fs::is_regular_file(given / kRobotFile, ec)) {
      throw std::invalid_argument(given.string() +
                                  ": no robot.yaml there (a robot folder holds one)");
    }
    return Read(fs::absolute(given).lexically_normal());
  }
  const auto folders = Folders(models_dir);
  const auto it = folders.find(name_or_folder);
  if (it == folders.end()) {
    std::string known, where;
    for (const auto& [name, folder] : folders) known += (known.empty() ? "" : ", ") + name;
    for (const std::string& p : RobotSearchPath(models_dir))
      where += (where.empty() ? "" : ", ") + p;
    throw std::invalid_argument("unknown robot '" + name_or_folder + "'; known robots: " + known +
                                " (found in " + where +
                                "; add folders with MARIONETTE_ROBOT_PATH or give a robot folder)");
  }
  return Read(fs::absolute(it->second).lexically_normal());
}

std::vector<int> HeldBaseVelocities(const RobotInfo& robot) {
  if (robot.base == "planar") return {0, 1, 2};  // JointModelPlanar: vx vy wz, the first 3 of v
  return {};
}

std::string ToJson(const RobotInfo& r) {
  nlohmann::ordered_json grippers = nlohmann::ordered_json::array();
  for (const GripperInfo& g : r.grippers) {
    grippers.push_back({{"name", g.name},
                        {"joint", g.joint},
                        {"open_position", g.open_position},
                        {"closed_position", g.closed_position}});
  }
  const nlohmann::ordered_json j = {{"name", r.name},
                                    {"directory", r.directory},
                                    {"urdf", r.urdf},
                                    {"srdf", r.srdf},
                                    {"mjcf", r.mjcf},
                                    {"base", r.base},
                                    {"reference", r.reference},
                                    {"contact_bodies", r.contact_bodies},
                                    {"grip_bodies", r.grip_bodies},
                                    {"camera", r.camera},
                                    {"camera_frame", r.camera_frame},
                                    {"grippers", grippers}};
  return j.dump();
}

}  // namespace marionette::controller
