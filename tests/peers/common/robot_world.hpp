// What the robot driver stand-ins share: the room and boxes they drive in, the lidar they ray-cast, the
// unicycle they move, the operator on stdin and the log lines the tests read.
//
// --log FILE lines:
//   cmd <receive unix ns> <linear.x %a> <angular.z %a>
//   scan <stamp sec> <stamp nanosec> <ranges as %a, space separated>
#pragma once

#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <limits>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace robot_world {

struct Box {
    double x, y, hx, hy, yaw;
};

struct World {
    std::string ns = "robot_1";
    double x = 0, y = 0, yaw = 0;
    double xmin = 0, ymin = 0, xmax = 4, ymax = 6, radius = 0.165;
    std::vector<Box> boxes;
    int beams = 360;
    double scan_hz = 10, odom_hz = 50, truth_hz = 50, cmd_timeout = 0.5, range_max = 12.0, range_min = 0.12;
    std::string log;
};

inline std::vector<std::string> split(const std::string& text, char sep) {
    std::vector<std::string> out;
    std::stringstream ss(text);
    std::string item;
    while (std::getline(ss, item, sep)) out.push_back(item);
    return out;
}

// the comma-separated numbers of `flag`'s value; an empty result: not `n` of them
inline std::vector<double> numbers(const std::string& text, size_t n) {
    auto parts = split(text, ',');
    std::vector<double> out;
    if (parts.size() != n) return out;
    for (auto& p : parts) out.push_back(std::stod(p));
    return out;
}

// takes one of the shared flags into `w`: true if `flag` was one of them; `bad` gets what is wrong with its value
inline bool world_flag(World& w, const std::string& flag, const std::string& v, std::string& bad) {
    auto need = [&](size_t n) {
        auto out = numbers(v, n);
        if (out.empty()) bad = flag + " takes " + std::to_string(n) + " comma-separated numbers";
        return out;
    };
    if (flag == "--ns") w.ns = v;
    else if (flag == "--start") { auto n = need(3); if (!n.empty()) { w.x = n[0]; w.y = n[1]; w.yaw = n[2]; } }
    else if (flag == "--room") { auto n = need(4); if (!n.empty()) { w.xmin = n[0]; w.ymin = n[1]; w.xmax = n[2]; w.ymax = n[3]; } }
    else if (flag == "--box") { auto n = need(5); if (!n.empty()) w.boxes.push_back({n[0], n[1], n[2], n[3], n[4]}); }
    else if (flag == "--beams") w.beams = std::stoi(v);
    else if (flag == "--scan-hz") w.scan_hz = std::stod(v);
    else if (flag == "--odom-hz") w.odom_hz = std::stod(v);
    else if (flag == "--truth-hz") w.truth_hz = std::stod(v);
    else if (flag == "--log") w.log = v;
    else return false;
    return true;
}

inline int64_t unix_ns() {
    return std::chrono::duration_cast<std::chrono::nanoseconds>(
               std::chrono::system_clock::now().time_since_epoch())
        .count();
}

// distance along the ray (ox, oy) + t (dx, dy) to the first wall or box face; +inf if none
inline double cast(const World& o, double ox, double oy, double dx, double dy) {
    double best = std::numeric_limits<double>::infinity();
    auto slab = [&](double px, double py, double ux, double uy, double hx, double hy, bool inside) {
        // ray in a rectangle's frame, centred at the origin with half sizes hx, hy
        double t0 = -std::numeric_limits<double>::infinity(), t1 = std::numeric_limits<double>::infinity();
        double p[2] = {px, py}, u[2] = {ux, uy}, h[2] = {hx, hy};
        for (int k = 0; k < 2; ++k) {
            if (std::abs(u[k]) < 1e-12) {
                if (std::abs(p[k]) > h[k]) return;
                continue;
            }
            double a = (-h[k] - p[k]) / u[k], b = (h[k] - p[k]) / u[k];
            if (a > b) std::swap(a, b);
            t0 = std::max(t0, a);
            t1 = std::min(t1, b);
        }
        if (t0 > t1) return;
        double t = inside ? t1 : t0;
        if (t > 0 && t < best) best = t;
    };
    double cx = 0.5 * (o.xmin + o.xmax), cy = 0.5 * (o.ymin + o.ymax);
    slab(ox - cx, oy - cy, dx, dy, 0.5 * (o.xmax - o.xmin), 0.5 * (o.ymax - o.ymin), true);
    for (const Box& b : o.boxes) {
        double c = std::cos(-b.yaw), s = std::sin(-b.yaw);
        double px = ox - b.x, py = oy - b.y;
        slab(c * px - s * py, s * px + c * py, c * dx - s * dy, s * dx + c * dy, b.hx, b.hy, false);
    }
    return best;
}

// the ranges of a full-circle scan from the pose (x, y, th): beyond range_max is +inf
inline std::vector<float> scan_ranges(const World& o, double x, double y, double th) {
    std::vector<float> ranges(o.beams);
    for (int i = 0; i < o.beams; ++i) {
        double a = th - M_PI + 2 * M_PI * i / o.beams;
        double r = cast(o, x, y, std::cos(a), std::sin(a));
        ranges[i] = r > o.range_max ? std::numeric_limits<float>::infinity() : static_cast<float>(r);
    }
    return ranges;
}

// the robot's motion: ground truth (x, y, th) in the room, kept off the walls, and the odometry's own
// integration (ox, oy, oth) of the same motion from where it started
struct Unicycle {
    double x, y, th, ox = 0, oy = 0, oth = 0;

    void step(const World& o, double v, double w, double dt) {
        double nx = x + v * std::cos(th) * dt, ny = y + v * std::sin(th) * dt;
        nx = std::min(std::max(nx, o.xmin + o.radius), o.xmax - o.radius);
        ny = std::min(std::max(ny, o.ymin + o.radius), o.ymax - o.radius);
        double moved = std::hypot(nx - x, ny - y);
        x = nx, y = ny, th = std::remainder(th + w * dt, 2 * M_PI);
        ox += moved * std::cos(oth), oy += moved * std::sin(oth), oth = std::remainder(oth + w * dt, 2 * M_PI);
    }
};

inline void log_scan(FILE* log, int32_t sec, uint32_t nanosec, const std::vector<float>& ranges) {
    std::fprintf(log, "scan %d %u", sec, nanosec);
    for (float r : ranges) std::fprintf(log, " %a", static_cast<double>(r));
    std::fprintf(log, "\n");
}

}  // namespace robot_world
