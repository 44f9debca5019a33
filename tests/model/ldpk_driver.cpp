// A command-line driver for the four standard models of Science-D-Visions' Lens Distortion
// Plugin Kit (LDPK), for camcal's equality tests. Compiled against an LDPK source tree
// (its headers only): g++ -O2 -std=c++11 -I$LDPK/include ldpk_driver.cpp -o ldpk_driver -pthread
//
// Usage:
//   ldpk_driver names MODEL          prints the model's LDPK name, then its parameter names, one a line
//   ldpk_driver < cases              evaluates cases read from stdin, each:
//       MODEL DIRECTION N_POINTS      (DIRECTION: undistort or distort)
//       FL_CM W_FB_CM H_FB_CM LCO_X_CM LCO_Y_CM PIXEL_ASPECT
//       N_PARAMETERS VALUE...         (in the model's own parameter order)
//       X_UNIT Y_UNIT                 (N_POINTS lines, LDPK unit coordinates)
//     and writes one line "X Y" per point (%.17g), as the plugin's undistort() / distort() return them.
// MODEL is camcal's name: 3de-classic, 3de4-radial-deg4, 3de4-anamorphic-deg4, 3de4-fisheye-deg8.

#include <ldpk/tde4_ldp_classic_3de_mixed.h>
#include <ldpk/tde4_ldp_radial_decentered_deg_4_cylindric.h>
#include <ldpk/tde4_ldp_anamorphic_deg_4_rotate_squeeze_xy.h>
#include <ldpk/tde4_ldp_radial_deg_8.h>

#include <cstdio>
#include <iostream>
#include <memory>
#include <string>

namespace {

std::unique_ptr<tde4_ld_plugin> make_model(const std::string& model) {
  typedef ldpk::vec2d V;
  typedef ldpk::mat2d M;
  if (model == "3de-classic") return std::unique_ptr<tde4_ld_plugin>(new tde4_ldp_classic_3de_mixed<V, M>());
  if (model == "3de4-radial-deg4")
    return std::unique_ptr<tde4_ld_plugin>(new tde4_ldp_radial_decentered_deg_4_cylindric<V, M>());
  if (model == "3de4-anamorphic-deg4")
    return std::unique_ptr<tde4_ld_plugin>(new tde4_ldp_anamorphic_deg_4_rotate_squeeze_xy<V, M>());
  if (model == "3de4-fisheye-deg8") return std::unique_ptr<tde4_ld_plugin>(new tde4_ldp_radial_deg_8<V, M>());
  return std::unique_ptr<tde4_ld_plugin>();
}

int print_names(const std::string& model) {
  std::unique_ptr<tde4_ld_plugin> plugin = make_model(model);
  if (!plugin) {
    std::cerr << "unknown model " << model << std::endl;
    return 2;
  }
  char text[1024];
  plugin->getModelName(text);
  std::cout << text << "\n";
  int n = 0;
  plugin->getNumParameters(n);
  for (int i = 0; i < n; ++i) {
    plugin->getParameterName(i, text);
    std::cout << text << "\n";
  }
  return 0;
}

int run_cases() {
  static const char* builtins[6] = {"tde4_focal_length_cm", "tde4_filmback_width_cm", "tde4_filmback_height_cm",
                                    "tde4_lens_center_offset_x_cm", "tde4_lens_center_offset_y_cm",
                                    "tde4_pixel_aspect"};
  std::string model, direction;
  int n_points = 0;
  while (std::cin >> model >> direction >> n_points) {
    std::unique_ptr<tde4_ld_plugin> plugin = make_model(model);
    if (!plugin || (direction != "undistort" && direction != "distort")) {
      std::cerr << "bad case header: " << model << " " << direction << std::endl;
      return 2;
    }
    for (int i = 0; i < 6; ++i) {
      double value = 0.0;
      std::cin >> value;
      plugin->setParameterValue(builtins[i], value);
    }
    int n_parameters = 0, n_model = 0;
    std::cin >> n_parameters;
    plugin->getNumParameters(n_model);
    if (n_parameters != n_model) {
      std::cerr << model << " has " << n_model << " parameters, the case gives " << n_parameters << std::endl;
      return 2;
    }
    char name[1024];
    for (int i = 0; i < n_parameters; ++i) {
      double value = 0.0;
      std::cin >> value;
      plugin->getParameterName(i, name);
      plugin->setParameterValue(name, value);
    }
    plugin->initializeParameters();
    for (int i = 0; i < n_points; ++i) {
      double x = 0.0, y = 0.0, x_out = 0.0, y_out = 0.0;
      std::cin >> x >> y;
      if (direction == "undistort")
        plugin->undistort(x, y, x_out, y_out);
      else
        plugin->distort(x, y, x_out, y_out);
      std::printf("%.17g %.17g\n", x_out, y_out);
    }
  }
  return std::cin.eof() ? 0 : 2;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc == 3 && std::string(argv[1]) == "names") return print_names(argv[2]);
  if (argc == 1) return run_cases();
  std::cerr << "usage: ldpk_driver [names MODEL] < cases" << std::endl;
  return 2;
}
