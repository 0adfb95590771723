// Ceres reference solve of a BAL problem, the exact model of jaxba._bal and Ceres'
// examples/simple_bundle_adjuster.cc: P = R(r) X + t, p = -P[:2]/P[2],
// x = f (1 + k1 |p|^2 + k2 |p|^4) p, residual x - observed, cost 0.5 sum r^2.
// All parameters free, no robust loss, Levenberg-Marquardt, Ceres' default tolerances
// (function 1e-6, gradient 1e-10, parameter 1e-8).
//
// Usage: ceres_bal FILE.txt [LINEAR_SOLVER=SPARSE_SCHUR] [THREADS=1] [MAX_ITERATIONS=100]
// FILE.txt is a plain (decompressed) BAL file. Prints one JSON object on stdout.
// Built by benchmarks/bal_vs_ceres.py.

#include <sys/resource.h>

#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "ceres/ceres.h"
#include "ceres/rotation.h"

namespace {

struct BalProblem {
  int n_cameras = 0, n_points = 0, n_observations = 0;
  std::vector<int> camera_index, point_index;
  std::vector<double> observed, parameters;  // parameters: 9 per camera, then 3 per point

  double* camera(int i) { return parameters.data() + 9 * i; }
  double* point(int i) { return parameters.data() + 9 * n_cameras + 3 * i; }

  bool Read(const char* path) {
    FILE* file = std::fopen(path, "r");
    if (file == nullptr) return false;
    bool ok = std::fscanf(file, "%d %d %d", &n_cameras, &n_points, &n_observations) == 3;
    camera_index.resize(n_observations);
    point_index.resize(n_observations);
    observed.resize(2 * n_observations);
    for (int i = 0; ok && i < n_observations; ++i) {
      ok = std::fscanf(file, "%d %d %lf %lf", &camera_index[i], &point_index[i],
                       &observed[2 * i], &observed[2 * i + 1]) == 4;
    }
    parameters.resize(9 * n_cameras + 3 * n_points);
    for (double& value : parameters) {
      ok = ok && std::fscanf(file, "%lf", &value) == 1;
    }
    std::fclose(file);
    return ok;
  }
};

struct SnavelyReprojectionError {
  SnavelyReprojectionError(double x, double y) : observed_x(x), observed_y(y) {}

  template <typename T>
  bool operator()(const T* const camera, const T* const point, T* residuals) const {
    T p[3];
    ceres::AngleAxisRotatePoint(camera, point, p);
    p[0] += camera[3];
    p[1] += camera[4];
    p[2] += camera[5];
    const T xp = -p[0] / p[2];
    const T yp = -p[1] / p[2];
    const T r2 = xp * xp + yp * yp;
    const T distortion = 1.0 + r2 * (camera[7] + camera[8] * r2);
    residuals[0] = camera[6] * distortion * xp - observed_x;
    residuals[1] = camera[6] * distortion * yp - observed_y;
    return true;
  }

  double observed_x, observed_y;
};

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s FILE.txt [LINEAR_SOLVER] [THREADS] [MAX_ITERATIONS]\n",
                 argv[0]);
    return 2;
  }
  BalProblem bal;
  if (!bal.Read(argv[1])) {
    std::fprintf(stderr, "cannot read BAL file %s\n", argv[1]);
    return 2;
  }
  const std::string linear_solver = argc > 2 ? argv[2] : "SPARSE_SCHUR";
  const int threads = argc > 3 ? std::atoi(argv[3]) : 1;
  const int max_iterations = argc > 4 ? std::atoi(argv[4]) : 100;

  ceres::Problem problem;
  for (int i = 0; i < bal.n_observations; ++i) {
    auto* cost = new ceres::AutoDiffCostFunction<SnavelyReprojectionError, 2, 9, 3>(
        new SnavelyReprojectionError(bal.observed[2 * i], bal.observed[2 * i + 1]));
    problem.AddResidualBlock(cost, nullptr, bal.camera(bal.camera_index[i]),
                             bal.point(bal.point_index[i]));
  }

  ceres::Solver::Options options;
  if (!ceres::StringToLinearSolverType(linear_solver, &options.linear_solver_type)) {
    std::fprintf(stderr, "unknown linear solver %s\n", linear_solver.c_str());
    return 2;
  }
  options.minimizer_progress_to_stdout = false;
  options.num_threads = threads;
  options.max_num_iterations = max_iterations;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);

  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  std::printf(
      "{\"solver\": \"ceres %s\", \"linear_solver\": \"%s\", \"threads\": %d, "
      "\"initial_cost\": %.17g, \"final_cost\": %.17g, \"iterations\": %d, "
      "\"successful_iterations\": %d, \"solve_seconds\": %.6f, "
      "\"linear_solver_seconds\": %.6f, \"converged\": %s, \"termination\": \"%s\", "
      "\"peak_rss_mib\": %.1f}\n",
      CERES_VERSION_STRING, linear_solver.c_str(), threads, summary.initial_cost,
      summary.final_cost, summary.num_successful_steps + summary.num_unsuccessful_steps,
      summary.num_successful_steps, summary.total_time_in_seconds,
      summary.linear_solver_time_in_seconds,
      summary.termination_type == ceres::CONVERGENCE ? "true" : "false",
      ceres::TerminationTypeToString(summary.termination_type), usage.ru_maxrss / 1024.0);
  return 0;
}
