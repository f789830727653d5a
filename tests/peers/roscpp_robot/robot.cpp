// A robot driver stand-in on roscpp: what a ROS 1 robot's base and lidar drivers put on a ROS 1 master.
//
// Subscribes to /<ns>/cmd_vel (geometry_msgs/Twist, TCP_NODELAY), moves a unicycle by the latest command
// (held at most --cmd-timeout s, as a base's watchdog does), and publishes /<ns>/scan (sensor_msgs/LaserScan,
// ray-cast against the room and boxes given on the command line), /<ns>/odom (nav_msgs/Odometry, integrated
// from its own start) and /<ns>/ground_truth (geometry_msgs/PoseStamped, standing for motion capture).
// Types are Debian's ROS 1 message packages (the standard md5sums); the master is ROS_MASTER_URI's.
//
// stdin takes an operator's lines: "reset" puts the robot at its start (answers "reset <n>" on stdout),
// "quit" ends the process. stdout announces "ready <ns>" once the endpoints are advertised.
// --log FILE gets one line per command received and per scan published (see robot_world.hpp).
#include <atomic>
#include <mutex>
#include <string>
#include <thread>

#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/Twist.h>
#include <nav_msgs/Odometry.h>
#include <ros/ros.h>
#include <sensor_msgs/LaserScan.h>

#include "robot_world.hpp"

using robot_world::World;

namespace {

[[noreturn]] void usage(const std::string& why) {
    std::cerr << "mrl_roscpp_robot: " << why << "\n"
              << "usage: mrl_roscpp_robot --ns NAME --start X,Y,YAW --room XMIN,YMIN,XMAX,YMAX\n"
              << "  [--box CX,CY,HALF_X,HALF_Y,YAW]... [--beams N] [--scan-hz F] [--odom-hz F] [--truth-hz F]\n"
              << "  [--log FILE]\n";
    std::exit(2);
}

World parse(int argc, char** argv) {
    World o;
    for (int i = 1; i < argc; ++i) {
        std::string flag = argv[i];
        if (i + 1 >= argc) usage(flag + " needs a value");
        std::string bad;
        if (!robot_world::world_flag(o, flag, argv[++i], bad)) usage("unknown option " + flag);
        if (!bad.empty()) usage(bad);
    }
    return o;
}

struct Command {
    std::mutex lock;
    double v = 0, w = 0;
    int64_t received_ns = 0;
    FILE* log = nullptr;

    void take(const geometry_msgs::Twist::ConstPtr& msg) {
        int64_t now = robot_world::unix_ns();
        std::lock_guard<std::mutex> guard(lock);
        v = msg->linear.x;
        w = msg->angular.z;
        received_ns = now;
        if (log) std::fprintf(log, "cmd %lld %a %a\n", static_cast<long long>(now), v, w);
    }
};

void stamp(std_msgs::Header& h, int64_t ns, const std::string& frame) {
    h.stamp.sec = static_cast<uint32_t>(ns / 1000000000LL);
    h.stamp.nsec = static_cast<uint32_t>(ns % 1000000000LL);
    h.frame_id = frame;
}

}  // namespace

int main(int argc, char** argv) {
    World o = parse(argc, argv);
    FILE* log = o.log.empty() ? nullptr : std::fopen(o.log.c_str(), "w");
    if (!o.log.empty() && !log) usage("cannot write " + o.log);
    int ros_argc = 1;
    ros::init(ros_argc, argv, "mrl_roscpp_robot_" + o.ns, ros::init_options::NoSigintHandler);
    if (!ros::master::check()) {
        std::cerr << "mrl_roscpp_robot: no ROS master at " << ros::master::getURI() << "\n";
        return 1;
    }
    ros::NodeHandle nh;
    std::string prefix = "/" + o.ns + "/";
    ros::Publisher scan_pub = nh.advertise<sensor_msgs::LaserScan>(prefix + "scan", 10);
    ros::Publisher odom_pub = nh.advertise<nav_msgs::Odometry>(prefix + "odom", 10);
    ros::Publisher truth_pub = nh.advertise<geometry_msgs::PoseStamped>(prefix + "ground_truth", 10);
    Command command;
    command.log = log;
    ros::Subscriber cmd_sub = nh.subscribe(
        prefix + "cmd_vel", 10, &Command::take, &command, ros::TransportHints().tcpNoDelay());
    ros::AsyncSpinner spinner(1);
    spinner.start();

    std::atomic<bool> quit{false};
    std::atomic<int> resets{0};
    std::thread operator_thread([&] {
        std::string line;
        while (std::getline(std::cin, line)) {
            if (line == "reset") resets++;
            else if (line == "quit") break;
        }
        quit = true;
    });
    std::cout << "ready " << o.ns << std::endl;

    robot_world::Unicycle body{o.x, o.y, o.yaw};
    int handled_resets = 0;
    const double dt = 0.005;
    const auto t0 = std::chrono::steady_clock::now();
    int64_t step = 0, next_scan = 0, next_odom = 0, next_truth = 0;
    const int64_t scan_every = std::llround(1.0 / (o.scan_hz * dt));
    const int64_t odom_every = std::llround(1.0 / (o.odom_hz * dt));
    const int64_t truth_every = std::llround(1.0 / (o.truth_hz * dt));
    sensor_msgs::LaserScan scan;
    scan.angle_min = static_cast<float>(-M_PI);
    scan.angle_increment = static_cast<float>(2 * M_PI / o.beams);
    scan.angle_max = static_cast<float>(-M_PI + 2 * M_PI / o.beams * (o.beams - 1));
    scan.scan_time = static_cast<float>(1.0 / o.scan_hz);
    scan.time_increment = static_cast<float>(1.0 / o.scan_hz / o.beams);
    scan.range_min = static_cast<float>(o.range_min);
    scan.range_max = static_cast<float>(o.range_max);
    while (!quit && ros::ok()) {
        if (resets > handled_resets) {
            handled_resets = resets;
            body = robot_world::Unicycle{o.x, o.y, o.yaw};
            {
                std::lock_guard<std::mutex> guard(command.lock);
                command.v = command.w = 0;
            }
            std::cout << "reset " << handled_resets << std::endl;
        }
        double v, w;
        int64_t now = robot_world::unix_ns();
        {
            std::lock_guard<std::mutex> guard(command.lock);
            bool fresh = (now - command.received_ns) < static_cast<int64_t>(o.cmd_timeout * 1e9);
            v = fresh ? command.v : 0.0;
            w = fresh ? command.w : 0.0;
        }
        body.step(o, v, w, dt);
        if (step >= next_truth) {
            next_truth += truth_every;
            geometry_msgs::PoseStamped pose;
            stamp(pose.header, now, "map");
            pose.pose.position.x = body.x;
            pose.pose.position.y = body.y;
            pose.pose.orientation.z = std::sin(body.th / 2);
            pose.pose.orientation.w = std::cos(body.th / 2);
            truth_pub.publish(pose);
        }
        if (step >= next_odom) {
            next_odom += odom_every;
            nav_msgs::Odometry odom;
            stamp(odom.header, now, o.ns + "/odom");
            odom.child_frame_id = o.ns + "/base_link";
            odom.pose.pose.position.x = body.ox;
            odom.pose.pose.position.y = body.oy;
            odom.pose.pose.orientation.z = std::sin(body.oth / 2);
            odom.pose.pose.orientation.w = std::cos(body.oth / 2);
            odom.twist.twist.linear.x = v;
            odom.twist.twist.angular.z = w;
            odom_pub.publish(odom);
        }
        if (step >= next_scan) {
            next_scan += scan_every;
            scan.ranges = robot_world::scan_ranges(o, body.x, body.y, body.th);
            stamp(scan.header, now, o.ns + "/laser");
            scan_pub.publish(scan);
            if (log) {  // the subscriber logs commands from the spinner's thread: one line at a time
                std::lock_guard<std::mutex> guard(command.lock);
                robot_world::log_scan(log, static_cast<int32_t>(scan.header.stamp.sec), scan.header.stamp.nsec,
                                      scan.ranges);
            }
        }
        if (log) {
            std::lock_guard<std::mutex> guard(command.lock);
            std::fflush(log);
        }
        ++step;
        std::this_thread::sleep_until(t0 + std::chrono::nanoseconds(static_cast<int64_t>(step * dt * 1e9)));
    }
    spinner.stop();
    ros::shutdown();
    if (log) std::fclose(log);
    operator_thread.detach();
    return 0;
}
