// marionette-urdf2mjcf IN.urdf OUT.xml
// Compiles a URDF with MuJoCo's own parser and saves the result as MJCF, which
// scripts/generate_models.py then extends (free joint, actuators, sole boxes, cameras).
// The URDF must carry real mesh paths and a <mujoco><compiler .../></mujoco> element.
#include <mujoco/mujoco.h>

#include <cstdio>

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: %s IN.urdf OUT.xml\n", argv[0]);
    return 2;
  }
  char error[1000] = "";
  mjModel* model = mj_loadXML(argv[1], nullptr, error, sizeof(error));
  if (model == nullptr) {
    std::fprintf(stderr, "MuJoCo could not load %s: %s\n", argv[1], error);
    return 1;
  }
  if (mj_saveLastXML(argv[2], model, error, sizeof(error)) == 0) {
    std::fprintf(stderr, "MuJoCo could not save %s: %s\n", argv[2], error);
    mj_deleteModel(model);
    return 1;
  }
  std::printf("%s: nq=%d nv=%d nbody=%d nmesh=%d -> %s\n", argv[1], model->nq, model->nv,
              model->nbody, model->nmesh, argv[2]);
  mj_deleteModel(model);
  return 0;
}
