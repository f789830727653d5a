// A robot driver stand-in on Fast DDS: what a ROS 2 robot running rmw_fastrtps puts on the wire.
//
// Subscribes to rt/<ns>/cmd_vel (geometry_msgs Twist, reliable), moves a unicycle by the latest
// command (held at most --cmd-timeout s, as a base's watchdog does), and publishes
// rt/<ns>/scan (sensor_msgs LaserScan, ray-cast against the room and boxes given on the command line),
// rt/<ns>/odom (nav_msgs Odometry, integrated from its own start) and rt/<ns>/ground_truth
// (geometry_msgs PoseStamped, standing for motion capture), each with the QoS given on the command line.
// Types come from fastddsgen over the IDL the pipeline writes (pkg::msg::dds_::Name_).
//
// stdin takes an operator's lines: "reset" puts the robot at its start (answers "reset <n>" on stdout),
// "quit" ends the process. stdout announces "ready" once the endpoints exist.
// --log FILE gets one line per command received and per scan published (see robot_world.hpp).
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <limits>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/domain/qos/DomainParticipantQos.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/publisher/qos/DataWriterQos.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/subscriber/qos/DataReaderQos.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastrtps/utils/IPLocator.h>

#include "robot_world.hpp"
#include "ros2_types.h"
#include "ros2_typesPubSubTypes.h"

using namespace eprosima::fastdds::dds;
namespace rtps = eprosima::fastrtps::rtps;

namespace {

struct QosSpec {
    bool reliable = true;
    bool transient_local = false;
    int depth = 10;
    std::string type_hash;
};

struct Options {
    robot_world::World world;
    int domain = 0;
    QosSpec scan, odom, truth, cmd;
    bool loopback = true;
};

[[noreturn]] void usage(const std::string& why) {
    std::cerr << "mrl_fastdds_robot: " << why << "\n"
              << "usage: mrl_fastdds_robot --domain N --ns NAME --start X,Y,YAW --room XMIN,YMIN,XMAX,YMAX\n"
              << "  [--box CX,CY,HALF_X,HALF_Y,YAW]... [--beams N] [--scan-hz F] [--odom-hz F] [--truth-hz F]\n"
              << "  [--qos-{scan,odom,truth,cmd} reliable|best_effort,volatile|transient_local,DEPTH,TYPEHASH]\n"
              << "  [--log FILE]\n";
    std::exit(2);
}

QosSpec qos_of(const std::string& text, const std::string& flag) {
    auto parts = robot_world::split(text, ',');
    if (parts.size() != 4) usage(flag + " takes RELIABILITY,DURABILITY,DEPTH,TYPEHASH");
    QosSpec q;
    q.reliable = parts[0] == "reliable";
    q.transient_local = parts[1] == "transient_local";
    q.depth = std::stoi(parts[2]);
    q.type_hash = parts[3];
    return q;
}

Options parse(int argc, char** argv) {
    Options o;
    for (int i = 1; i < argc; ++i) {
        std::string flag = argv[i];
        if (i + 1 >= argc) usage(flag + " needs a value");
        std::string v = argv[++i];
        std::string bad;
        if (robot_world::world_flag(o.world, flag, v, bad)) {
            if (!bad.empty()) usage(bad);
        } else if (flag == "--domain") o.domain = std::stoi(v);
        else if (flag == "--qos-scan") o.scan = qos_of(v, flag);
        else if (flag == "--qos-odom") o.odom = qos_of(v, flag);
        else if (flag == "--qos-truth") o.truth = qos_of(v, flag);
        else if (flag == "--qos-cmd") o.cmd = qos_of(v, flag);
        else if (flag == "--loopback") o.loopback = v == "1";
        else usage("unknown option " + flag);
    }
    return o;
}

template <class Header>
void stamp(Header& h, int64_t ns, const std::string& frame) {
    h.stamp().sec(static_cast<int32_t>(ns / 1000000000LL));
    h.stamp().nanosec(static_cast<uint32_t>(ns % 1000000000LL));
    h.frame_id(frame);
}

class CommandListener : public DataReaderListener {
public:
    std::mutex lock;
    double v = 0, w = 0;
    int64_t received_ns = 0;
    FILE* log = nullptr;

    void on_data_available(DataReader* reader) override {
        geometry_msgs::msg::dds_::Twist_ msg;
        SampleInfo info;
        while (reader->take_next_sample(&msg, &info) == ReturnCode_t::RETCODE_OK) {
            if (!info.valid_data) continue;
            int64_t now = robot_world::unix_ns();
            std::lock_guard<std::mutex> guard(lock);
            v = msg.linear().x();
            w = msg.angular().z();
            received_ns = now;
            if (log) std::fprintf(log, "cmd %lld %a %a\n", static_cast<long long>(now), v, w);
        }
    }
};

void apply(const QosSpec& q, ReliabilityQosPolicy& rel, DurabilityQosPolicy& dur, HistoryQosPolicy& hist) {
    rel.kind = q.reliable ? RELIABLE_RELIABILITY_QOS : BEST_EFFORT_RELIABILITY_QOS;
    dur.kind = q.transient_local ? TRANSIENT_LOCAL_DURABILITY_QOS : VOLATILE_DURABILITY_QOS;
    hist.kind = KEEP_LAST_HISTORY_QOS;
    hist.depth = q.depth;
}

std::vector<eprosima::fastrtps::rtps::octet> user_data(const QosSpec& q) {
    std::string text = "typehash=" + q.type_hash + ";";
    return {text.begin(), text.end()};
}

}  // namespace

int main(int argc, char** argv) {
    Options opts = parse(argc, argv);
    const robot_world::World& o = opts.world;
    FILE* log = o.log.empty() ? nullptr : std::fopen(o.log.c_str(), "w");
    if (!o.log.empty() && !log) usage("cannot write " + o.log);

    DomainParticipantQos pqos;
    pqos.name("mrl_fastdds_robot_" + o.ns);
    if (opts.loopback) {
        // loopback only, unicast discovery of 127.0.0.1 (as ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST)
        pqos.transport().use_builtin_transports = false;
        auto udp = std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>();
        udp->interfaceWhiteList.push_back("127.0.0.1");
        udp->maxInitialPeersRange = 32;
        pqos.transport().user_transports.push_back(udp);
        rtps::Locator_t peer;
        rtps::IPLocator::setIPv4(peer, 127, 0, 0, 1);
        pqos.wire_protocol().builtin.initialPeersList.push_back(peer);
        pqos.wire_protocol().builtin.avoid_builtin_multicast = true;
    }
    DomainParticipant* participant = DomainParticipantFactory::get_instance()->create_participant(opts.domain, pqos);
    if (!participant) {
        std::cerr << "mrl_fastdds_robot: cannot create a participant on domain " << opts.domain << "\n";
        return 1;
    }
    TypeSupport scan_type(new sensor_msgs::msg::dds_::LaserScan_PubSubType());
    TypeSupport odom_type(new nav_msgs::msg::dds_::Odometry_PubSubType());
    TypeSupport pose_type(new geometry_msgs::msg::dds_::PoseStamped_PubSubType());
    TypeSupport twist_type(new geometry_msgs::msg::dds_::Twist_PubSubType());
    for (TypeSupport* t : {&scan_type, &odom_type, &pose_type, &twist_type}) t->register_type(participant);

    std::string prefix = "rt/" + o.ns + "/";
    Topic* scan_topic = participant->create_topic(prefix + "scan", scan_type.get_type_name(), TOPIC_QOS_DEFAULT);
    Topic* odom_topic = participant->create_topic(prefix + "odom", odom_type.get_type_name(), TOPIC_QOS_DEFAULT);
    Topic* truth_topic = participant->create_topic(prefix + "ground_truth", pose_type.get_type_name(), TOPIC_QOS_DEFAULT);
    Topic* cmd_topic = participant->create_topic(prefix + "cmd_vel", twist_type.get_type_name(), TOPIC_QOS_DEFAULT);
    Publisher* pub = participant->create_publisher(PUBLISHER_QOS_DEFAULT);
    Subscriber* sub = participant->create_subscriber(SUBSCRIBER_QOS_DEFAULT);

    auto writer = [&](Topic* topic, const QosSpec& q) {
        DataWriterQos wq = DATAWRITER_QOS_DEFAULT;
        apply(q, wq.reliability(), wq.durability(), wq.history());
        wq.user_data().data_vec(user_data(q));
        wq.representation().m_value.push_back(XCDR_DATA_REPRESENTATION);
        return pub->create_datawriter(topic, wq);
    };
    DataWriter* scan_writer = writer(scan_topic, opts.scan);
    DataWriter* odom_writer = writer(odom_topic, opts.odom);
    DataWriter* truth_writer = writer(truth_topic, opts.truth);
    CommandListener listener;
    listener.log = log;
    DataReaderQos rq = DATAREADER_QOS_DEFAULT;
    apply(opts.cmd, rq.reliability(), rq.durability(), rq.history());
    rq.user_data().data_vec(user_data(opts.cmd));
    DataReader* cmd_reader = sub->create_datareader(cmd_topic, rq, &listener);
    if (!scan_writer || !odom_writer || !truth_writer || !cmd_reader) {
        std::cerr << "mrl_fastdds_robot: cannot create the endpoints of " << o.ns << "\n";
        return 1;
    }

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

    // state: pose in the map (ground truth) and the odometry's own integration from where it started
    robot_world::Unicycle body{o.x, o.y, o.yaw};
    int handled_resets = 0;
    const double dt = 0.005;
    const auto t0 = std::chrono::steady_clock::now();
    int64_t step = 0, next_scan = 0, next_odom = 0, next_truth = 0;
    const int64_t scan_every = std::llround(1.0 / (o.scan_hz * dt));
    const int64_t odom_every = std::llround(1.0 / (o.odom_hz * dt));
    const int64_t truth_every = std::llround(1.0 / (o.truth_hz * dt));
    sensor_msgs::msg::dds_::LaserScan_ scan;
    scan.angle_min(static_cast<float>(-M_PI));
    scan.angle_increment(static_cast<float>(2 * M_PI / o.beams));
    scan.angle_max(static_cast<float>(-M_PI + 2 * M_PI / o.beams * (o.beams - 1)));
    scan.scan_time(static_cast<float>(1.0 / o.scan_hz));
    scan.time_increment(static_cast<float>(1.0 / o.scan_hz / o.beams));
    scan.range_min(static_cast<float>(o.range_min));
    scan.range_max(static_cast<float>(o.range_max));
    while (!quit) {
        if (resets > handled_resets) {
            handled_resets = resets;
            body = robot_world::Unicycle{o.x, o.y, o.yaw};
            {
                std::lock_guard<std::mutex> guard(listener.lock);
                listener.v = listener.w = 0;
            }
            std::cout << "reset " << handled_resets << std::endl;
        }
        double v, w;
        int64_t now = robot_world::unix_ns();
        {
            std::lock_guard<std::mutex> guard(listener.lock);
            bool fresh = (now - listener.received_ns) < static_cast<int64_t>(o.cmd_timeout * 1e9);
            v = fresh ? listener.v : 0.0;
            w = fresh ? listener.w : 0.0;
        }
        body.step(o, v, w, dt);
        if (step >= next_truth) {
            next_truth += truth_every;
            geometry_msgs::msg::dds_::PoseStamped_ pose;
            stamp(pose.header(), now, "map");
            pose.pose().position().x(body.x);
            pose.pose().position().y(body.y);
            pose.pose().orientation().z(std::sin(body.th / 2));
            pose.pose().orientation().w(std::cos(body.th / 2));
            truth_writer->write(&pose);
        }
        if (step >= next_odom) {
            next_odom += odom_every;
            nav_msgs::msg::dds_::Odometry_ odom;
            stamp(odom.header(), now, o.ns + "/odom");
            odom.child_frame_id(o.ns + "/base_link");
            odom.pose().pose().position().x(body.ox);
            odom.pose().pose().position().y(body.oy);
            odom.pose().pose().orientation().z(std::sin(body.oth / 2));
            odom.pose().pose().orientation().w(std::cos(body.oth / 2));
            odom.twist().twist().linear().x(v);
            odom.twist().twist().angular().z(w);
            odom_writer->write(&odom);
        }
        if (step >= next_scan) {
            next_scan += scan_every;
            std::vector<float> ranges = robot_world::scan_ranges(o, body.x, body.y, body.th);
            scan.ranges(ranges);
            stamp(scan.header(), now, o.ns + "/laser");
            scan_writer->write(&scan);
            if (log) {  // the listener logs commands from its own thread: one line at a time
                std::lock_guard<std::mutex> guard(listener.lock);
                robot_world::log_scan(log, scan.header().stamp().sec(), scan.header().stamp().nanosec(), ranges);
            }
        }
        if (log) {
            std::lock_guard<std::mutex> guard(listener.lock);
            std::fflush(log);
        }
        ++step;
        std::this_thread::sleep_until(t0 + std::chrono::nanoseconds(static_cast<int64_t>(step * dt * 1e9)));
    }
    participant->delete_contained_entities();
    DomainParticipantFactory::get_instance()->delete_participant(participant);
    if (log) std::fclose(log);
    operator_thread.detach();
    return 0;
}
