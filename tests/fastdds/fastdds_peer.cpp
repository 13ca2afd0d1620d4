// fastdds_peer: an eProsima Fast DDS 2.x participant for the project's interoperability tests
// (tests/test_fastdds_interop.py). Independent of Cyclone: its types come from this folder's automotive.idl
// through fastddsgen, its QoS are Fast DDS's own defaults unless asked otherwise.
//
//   fastdds_peer read TOPIC [TOPIC...] [--domain N] [--count N] [--qos default|rviz2] [--data]
//       One reader per topic. Prints "matched: N writer(s) on TOPIC" when its matches change, and every sample as
//       one JSON line {"topic": ..., "sample": {...}}. Octet arrays and sequences print as {"size", "crc32"}
//       (zlib's CRC-32), plus "base64" with --data. Ends after N samples of every topic (0: until stopped).
//   fastdds_peer write Circle --color C --x X --y Y --size S [--domain N] [--count N] [--period-ms MS]
//       A Shapes Demo circle (ShapeType) with Fast DDS's default writer QoS, written every MS ms (100).
//   fastdds_peer hostile TOPIC --kind KIND [--domain N] [--count N] [--period-ms MS]
//       Valid CDR but nonsense, for the tests of tests/test_hostile_samples.py: once a reader matched, writes
//       samples of one kind every MS ms (100): N of them (0: until stopped; as the reader may not know this writer
//       yet when it matched, a test waits for the reader's report instead), then prints "hostile: N written" and
//       stays until stopped. KIND:
//         PlatformControl, PlatformStatus: enum (blinkerStatus 99), nan, inf (float members), bad-ns (timestamp
//           nanoseconds 2e9); SensorObjects, VisionTopic: enum (classification 99), nan (size[1] NaN), many (the
//           bound's number of objects), empty; Circle: huge, zero, negative (shapesize), far (x 10^6);
//         rt/LidarTopic: mismatch (width and data length disagree), noxyz (fields i, j, k);
//         CameraImageData: short, long (a frame of 1 KiB, or 64 KiB + 1 KiB, under the 64 KiB frame's type name).
//       Writer QoS: Fast DDS's defaults with a deadline of 1 s (our readers request 11 s or more).
//   All: --participants N (participant ids probed on 127.0.0.1; without it Fast DDS's default, 4),
//         --socket-buffer BYTES (UDP send and receive buffers, 4 MiB; 0: the system's default),
//         --defaults (Fast DDS's own participant: see below; neither option above goes with it).
//
// QoS "default" is Fast DDS's default DataReaderQos; "rviz2" is what RViz2 asks for a point cloud: reliable,
// volatile, keep last 5. Traffic stays on loopback: UDPv4 on 127.0.0.1 only, shared memory off, no multicast,
// initial peer 127.0.0.1 probed for participant ids 0..N-1 (Fast DDS's default range unless --participants: the
// project's participants must find it, as they find any tool started on the host). With --defaults the participant
// is Fast DDS's default one instead, as an application that configures nothing gets it: the built-in transports
// (UDPv4 on every interface and shared memory) and discovery (announced by multicast on every interface, lo included;
// Fast DDS 2.9 probes no unicast port by default); only its name is set. That multicasts on every interface of the
// host: run it only inside a test's own network namespace (and, as it also uses shared memory, with a /dev/shm of the
// test's: tests/fastdds_peer.py). SIGINT/SIGTERM end it cleanly.

#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <functional>
#include <iostream>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <type_traits>
#include <vector>

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/DataWriterListener.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastrtps/utils/IPLocator.h>

#include "automotivePubSubTypes.h"

using namespace eprosima::fastdds::dds;

namespace {

constexpr uint32_t DEFAULT_PARTICIPANTS = 0;  // 0: Fast DDS's own maxInitialPeersRange
constexpr uint32_t SOCKET_BUFFER = 4 * 1024 * 1024;  // room for a burst of 4 MiB camera frame fragments

std::atomic<bool> stop_requested{false};
bool print_octets = false;
std::mutex output_mutex;

void print_line(const std::string& line)
{
    std::lock_guard<std::mutex> lock(output_mutex);
    std::cout << line << std::endl;
}

[[noreturn]] void usage_error(const std::string& message)
{
    std::cerr << "fastdds_peer: " << message << std::endl;
    std::exit(2);
}

// ---- JSON text of the generated types ----------------------------------------------------------------------------

std::string json(bool value) { return value ? "true" : "false"; }
std::string json(int32_t value) { return std::to_string(value); }
std::string json(uint32_t value) { return std::to_string(value); }
std::string json(uint8_t value) { return std::to_string(value); }

std::string json(float value)
{
    if (!std::isfinite(value)) {
        return "null";
    }
    char text[32];
    std::snprintf(text, sizeof text, "%.17g", static_cast<double>(value));  // reads back as the same double
    return text;
}

std::string json(const std::string& value)
{
    std::string out = "\"";
    for (char c : value) {
        if (c == '"' || c == '\\') {
            out += '\\';
            out += c;
        } else if (static_cast<unsigned char>(c) < 0x20) {
            char escaped[8];
            std::snprintf(escaped, sizeof escaped, "\\u%04x", c);
            out += escaped;
        } else {
            out += c;
        }
    }
    return out + "\"";
}

template <size_t N>  // bounded strings (ShapeType's string<128> color)
std::string json(const eprosima::fastrtps::fixed_string<N>& value)
{
    return json(std::string(value.c_str()));
}

template <typename E, std::enable_if_t<std::is_enum<E>::value, int> = 0>
std::string json(E value)
{
    return std::to_string(static_cast<uint32_t>(value));
}

uint32_t crc32(const uint8_t* data, size_t size)
{
    static const std::vector<uint32_t> table = [] {
        std::vector<uint32_t> t(256);
        for (uint32_t n = 0; n < 256; ++n) {
            uint32_t c = n;
            for (int k = 0; k < 8; ++k) {
                c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
            }
            t[n] = c;
        }
        return t;
    }();
    uint32_t crc = 0xFFFFFFFFu;
    for (size_t i = 0; i < size; ++i) {
        crc = table[(crc ^ data[i]) & 0xFF] ^ (crc >> 8);
    }
    return crc ^ 0xFFFFFFFFu;
}

std::string base64(const uint8_t* data, size_t size)
{
    static const char alphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    std::string out;
    out.reserve((size + 2) / 3 * 4);
    for (size_t i = 0; i < size; i += 3) {
        uint32_t chunk = data[i] << 16;
        if (i + 1 < size) chunk |= data[i + 1] << 8;
        if (i + 2 < size) chunk |= data[i + 2];
        out += alphabet[(chunk >> 18) & 63];
        out += alphabet[(chunk >> 12) & 63];
        out += i + 1 < size ? alphabet[(chunk >> 6) & 63] : '=';
        out += i + 2 < size ? alphabet[chunk & 63] : '=';
    }
    return out;
}

std::string octets(const uint8_t* data, size_t size)
{
    std::string out = "{\"size\": " + std::to_string(size) + ", \"crc32\": " + std::to_string(crc32(data, size));
    if (print_octets) {
        out += ", \"base64\": \"" + base64(data, size) + "\"";
    }
    return out + "}";
}

std::string json(const std::vector<uint8_t>& value) { return octets(value.data(), value.size()); }

template <size_t N>
std::string json(const std::array<uint8_t, N>& value) { return octets(value.data(), N); }

// The generated structs, defined below; declared first so that the list templates find them.
std::string json(const POSIXTimestamp& t);
std::string json(const Sensor::SensorObject& o);
std::string json(const Vision::VisionObject& o);
std::string json(const sensor_msgs::msg::dds_::PointField_& f);

template <typename T>
std::string json_list(const T& items)
{
    std::string out = "[";
    for (const auto& item : items) {
        out += (out.size() > 1 ? ", " : "") + json(item);
    }
    return out + "]";
}

template <typename T, size_t N>
std::string json(const std::array<T, N>& items) { return json_list(items); }

template <typename T>
std::string json(const std::vector<T>& items) { return json_list(items); }

// {"name": value, ...} from (name, JSON text) pairs, in the IDL's member order.
std::string object(std::initializer_list<std::pair<const char*, std::string>> members)
{
    std::string out = "{";
    for (const auto& member : members) {
        out += (out.size() > 1 ? ", " : "") + json(std::string(member.first)) + ": " + member.second;
    }
    return out + "}";
}

std::string json(const POSIXTimestamp& t) { return object({{"s", json(t.s())}, {"ns", json(t.ns())}}); }

std::string json(const Alerts::DriverAlerts& a)
{
    return object({{"blindSpotDriver", json(a.blindSpotDriver())}, {"blindSpotPassenger", json(a.blindSpotPassenger())},
                   {"frontCollision", json(a.frontCollision())}, {"backCollision", json(a.backCollision())},
                   {"parkingCollision", json(a.parkingCollision())}, {"driverAttention", json(a.driverAttention())}});
}

std::string json(const Platform::PlatformControl& c)
{
    return object({{"sample_id", json(c.sample_id())}, {"timestamp", json(c.timestamp())},
                   {"vehicleSteerAngle", json(c.vehicleSteerAngle())}, {"speed", json(c.speed())},
                   {"blinkerStatus", json(c.blinkerStatus())}});
}

std::string json(const Platform::PlatformStatus& s)
{
    return object({{"timestamp", json(s.timestamp())}, {"vehSpd", json(s.vehSpd())},
                   {"blinkerStatus", json(s.blinkerStatus())}, {"posGasPedal", json(s.posGasPedal())},
                   {"velocity", json(s.velocity())}, {"yawRate", json(s.yawRate())},
                   {"vehicleSteerAngle", json(s.vehicleSteerAngle())}});
}

std::string json(const Sensor::SensorObject& o)
{
    return object({{"classification", json(o.classification())}, {"position", json(o.position())},
                   {"velocity", json(o.velocity())}, {"size", json(o.size())}, {"amplitude", json(o.amplitude())},
                   {"rangeMode", json(o.rangeMode())}, {"rangeRate", json(o.rangeRate())}});
}

std::string json(const Sensor::SensorObjectList& l)
{
    return object({{"timestamp", json(l.timestamp())}, {"objects", json(l.objects())}});
}

std::string json(const Vision::VisionObject& o)
{
    return object({{"classification", json(o.classification())}, {"position", json(o.position())},
                   {"velocity", json(o.velocity())}, {"size", json(o.size())}});
}

std::string json(const Vision::VisionSensor& v)
{
    return object({{"id", json(v.id())}, {"timestamp", json(v.timestamp())}, {"objects", json(v.objects())}});
}

std::string json(const CameraImage::CameraImageData& f)
{
    return object({{"id", json(f.id())}, {"sec_", json(f.sec_())}, {"nanosec_", json(f.nanosec_())},
                   {"seqnum", json(f.seqnum())}, {"data", json(f.data())}});
}

std::string json(const sensor_msgs::msg::dds_::PointField_& f)
{
    return object({{"name_", json(f.name_())}, {"offset_", json(f.offset_())}, {"datatype_", json(f.datatype_())},
                   {"count_", json(f.count_())}});
}

std::string json(const sensor_msgs::msg::dds_::PointCloud2_& c)
{
    const auto& header = c.header_();
    std::string stamp = object({{"sec_", json(header.stamp_().sec_())}, {"nanosec_", json(header.stamp_().nanosec_())}});
    return object({{"header_", object({{"stamp_", stamp}, {"frame_id_", json(header.frame_id_())}})},
                   {"height_", json(c.height_())}, {"width_", json(c.width_())}, {"fields_", json(c.fields_())},
                   {"is_bigendian_", json(c.is_bigendian_())}, {"point_step_", json(c.point_step_())},
                   {"row_step_", json(c.row_step_())}, {"data_", json(c.data_())}, {"is_dense_", json(c.is_dense_())}});
}

std::string json(const ShapeType& s)
{
    return object({{"color", json(s.color())}, {"x", json(s.x())}, {"y", json(s.y())},
                   {"shapesize", json(s.shapesize())}});
}

// ---- readers -----------------------------------------------------------------------------------------------------

class MatchReporter : public DataReaderListener, public DataWriterListener
{
public:
    explicit MatchReporter(std::string topic) : topic_(std::move(topic)) {}

    void on_subscription_matched(DataReader*, const SubscriptionMatchedStatus& status) override
    {
        print_line("matched: " + std::to_string(status.current_count) + " writer(s) on " + topic_);
    }

    void on_publication_matched(DataWriter*, const PublicationMatchedStatus& status) override
    {
        print_line("matched: " + std::to_string(status.current_count) + " reader(s) on " + topic_);
    }

    void on_requested_incompatible_qos(DataReader*, const RequestedIncompatibleQosStatus& status) override
    {
        print_line("incompatible QoS: policy " + std::to_string(status.last_policy_id) + " on " + topic_);
    }

    void on_offered_incompatible_qos(DataWriter*, const OfferedIncompatibleQosStatus& status) override
    {
        print_line("incompatible QoS: policy " + std::to_string(status.last_policy_id) + " on " + topic_);
    }

private:
    std::string topic_;
};

// One topic being read: takes whatever arrived and prints it. Samples live on the heap (a camera frame is 4 MiB).
struct TopicReader
{
    std::string topic;
    DataReader* reader = nullptr;
    std::function<bool(DataReader*)> take_and_print;  // true when a sample was printed
    uint32_t printed = 0;
};

template <typename Sample>
std::function<bool(DataReader*)> printer(const std::string& topic)
{
    auto sample = std::make_shared<Sample>();
    return [sample, topic](DataReader* reader) {
        SampleInfo info;
        while (reader->take_next_sample(sample.get(), &info) == ReturnCode_t::RETCODE_OK) {
            if (info.valid_data) {
                print_line("{\"topic\": " + json(topic) + ", \"sample\": " + json(*sample) + "}");
                return true;
            }
        }
        return false;
    };
}

struct TopicType
{
    std::function<TypeSupport()> type_support;
    std::function<std::function<bool(DataReader*)>(const std::string&)> make_printer;
};

// The topics of the system (default names) and the type each carries.
const std::map<std::string, TopicType>& topic_types()
{
    static const std::map<std::string, TopicType> types = {
        {"VisionTopic", {[] { return TypeSupport(new Vision::VisionSensorPubSubType()); },
                         printer<Vision::VisionSensor>}},
        {"SensorObjects", {[] { return TypeSupport(new Sensor::SensorObjectListPubSubType()); },
                           printer<Sensor::SensorObjectList>}},
        {"PlatformControl", {[] { return TypeSupport(new Platform::PlatformControlPubSubType()); },
                             printer<Platform::PlatformControl>}},
        {"PlatformStatus", {[] { return TypeSupport(new Platform::PlatformStatusPubSubType()); },
                            printer<Platform::PlatformStatus>}},
        {"AlertTopic", {[] { return TypeSupport(new Alerts::DriverAlertsPubSubType()); },
                        printer<Alerts::DriverAlerts>}},
        {"rt/LidarTopic", {[] { return TypeSupport(new sensor_msgs::msg::dds_::PointCloud2_PubSubType()); },
                           printer<sensor_msgs::msg::dds_::PointCloud2_>}},
        {"CameraImageData", {[] { return TypeSupport(new CameraImage::CameraImageDataPubSubType()); },
                             printer<CameraImage::CameraImageData>}},
        {"Circle", {[] { return TypeSupport(new ShapeTypePubSubType()); }, printer<ShapeType>}},
    };
    return types;
}

// ---- participant -------------------------------------------------------------------------------------------------

DomainParticipant* create_participant(uint32_t domain, uint32_t participants, uint32_t socket_buffer,
                                      bool defaults)
{
    DomainParticipantQos qos = PARTICIPANT_QOS_DEFAULT;
    qos.name("fastdds_peer");
    if (defaults) {  // Fast DDS's own transports and discovery, nothing configured
        DomainParticipant* participant = DomainParticipantFactory::get_instance()->create_participant(domain, qos);
        if (participant == nullptr) {
            std::cerr << "fastdds_peer: cannot create a participant on domain " << domain << std::endl;
            std::exit(1);
        }
        return participant;
    }
    auto udp = std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>();
    udp->interfaceWhiteList.push_back("127.0.0.1");
    if (participants > 0) {
        udp->maxInitialPeersRange = participants;
    }
    if (socket_buffer > 0) {  // 0: Fast DDS's default (the system's)
        udp->sendBufferSize = socket_buffer;
        udp->receiveBufferSize = socket_buffer;
        qos.transport().send_socket_buffer_size = socket_buffer;
        qos.transport().listen_socket_buffer_size = socket_buffer;
    }
    qos.transport().use_builtin_transports = false;  // no shared memory, no default UDP transport
    qos.transport().user_transports.push_back(udp);

    // Port 0: Fast DDS fills in the well-known port of the participant id it gets. A unicast metatraffic locator
    // and no multicast one means no multicast at all.
    eprosima::fastrtps::rtps::Locator_t loopback;
    eprosima::fastrtps::rtps::IPLocator::setIPv4(loopback, 127, 0, 0, 1);
    qos.wire_protocol().builtin.metatrafficUnicastLocatorList.push_back(loopback);
    qos.wire_protocol().default_unicast_locator_list.push_back(loopback);
    qos.wire_protocol().builtin.initialPeersList.push_back(loopback);

    DomainParticipant* participant = DomainParticipantFactory::get_instance()->create_participant(domain, qos);
    if (participant == nullptr) {
        std::cerr << "fastdds_peer: cannot create a participant on domain " << domain << std::endl;
        std::exit(1);
    }
    return participant;
}

void on_signal(int) { stop_requested = true; }

struct Options
{
    std::string command;
    std::vector<std::string> topics;
    uint32_t domain = 0;
    uint32_t count = 0;
    std::string qos = "default";
    std::string color = "BLUE";
    std::string kind;
    int32_t x = 120, y = 135, size = 30;
    uint32_t period_ms = 100;
    uint32_t participants = DEFAULT_PARTICIPANTS;
    uint32_t socket_buffer = SOCKET_BUFFER;
    bool defaults = false;
    bool transport_options = false;  // --participants or --socket-buffer given
};

uint32_t number(const std::string& option, const char* text)
{
    char* end = nullptr;
    long value = std::strtol(text, &end, 10);
    if (*text == '\0' || *end != '\0' || value < 0 || value > 0x7FFFFFFF) {
        usage_error("option " + option + ": '" + text + "' is not a non-negative integer");
    }
    return static_cast<uint32_t>(value);
}

Options parse(int argc, char** argv)
{
    if (argc < 3 || (std::strcmp(argv[1], "read") != 0 && std::strcmp(argv[1], "write") != 0
                     && std::strcmp(argv[1], "hostile") != 0)) {
        usage_error("usage: fastdds_peer read TOPIC [TOPIC...] [--domain N] [--count N] [--qos default|rviz2] [--data]"
                    " | write Circle --color C --x X --y Y --size S [--domain N] [--count N] [--period-ms MS]"
                    " | hostile TOPIC --kind KIND [--domain N] [--count N] [--period-ms MS];"
                    " all: [--participants N] [--socket-buffer BYTES] | [--defaults]");
    }
    Options options;
    options.command = argv[1];
    for (int i = 2; i < argc; ++i) {
        std::string arg = argv[i];
        if (arg == "--data") {
            print_octets = true;
            continue;
        }
        if (arg == "--defaults") {
            options.defaults = true;
            continue;
        }
        if (arg.rfind("--", 0) != 0) {
            if (topic_types().count(arg) == 0) {
                usage_error("unknown topic '" + arg + "' (VisionTopic, SensorObjects, PlatformControl, PlatformStatus,"
                            " AlertTopic, rt/LidarTopic, CameraImageData, Circle)");
            }
            options.topics.push_back(arg);
            continue;
        }
        if (i + 1 >= argc) {
            usage_error("option " + arg + " needs a value");
        }
        const char* value = argv[++i];
        if (arg == "--domain") options.domain = number(arg, value);
        else if (arg == "--count") options.count = number(arg, value);
        else if (arg == "--qos") options.qos = value;
        else if (arg == "--color") options.color = value;
        else if (arg == "--kind") options.kind = value;
        else if (arg == "--x") options.x = static_cast<int32_t>(number(arg, value));
        else if (arg == "--y") options.y = static_cast<int32_t>(number(arg, value));
        else if (arg == "--size") options.size = static_cast<int32_t>(number(arg, value));
        else if (arg == "--period-ms") options.period_ms = number(arg, value);
        else if (arg == "--participants") options.participants = number(arg, value);
        else if (arg == "--socket-buffer") options.socket_buffer = number(arg, value);
        else usage_error("unknown option " + arg);
        options.transport_options = options.transport_options || arg == "--participants" || arg == "--socket-buffer";
    }
    if (options.defaults && options.transport_options) {
        usage_error("--defaults takes Fast DDS's own transports: --participants and --socket-buffer do not go with it");
    }
    if (options.topics.empty()) {
        usage_error("no topic given");
    }
    if (options.qos != "default" && options.qos != "rviz2") {
        usage_error("option --qos: '" + options.qos + "' is not default or rviz2");
    }
    if (options.command == "write" && (options.topics.size() != 1 || options.topics[0] != "Circle")) {
        usage_error("write: only the topic Circle can be written");
    }
    if (options.command == "hostile" && (options.topics.size() != 1 || options.kind.empty())) {
        usage_error("hostile: one topic and --kind KIND");
    }
    return options;
}

Topic* create_topic(DomainParticipant* participant, const std::string& name)
{
    TypeSupport type = topic_types().at(name).type_support();
    type.register_type(participant);  // under the type's scoped IDL name: the name on the wire
    return participant->create_topic(name, type.get_type_name(), TOPIC_QOS_DEFAULT);
}

template <typename Qos>
std::string describe(const Qos& qos)
{
    std::string text = qos.reliability().kind == RELIABLE_RELIABILITY_QOS ? "reliable" : "best effort";
    static const std::map<DurabilityQosPolicyKind, std::string> durability = {
        {VOLATILE_DURABILITY_QOS, ", volatile"}, {TRANSIENT_LOCAL_DURABILITY_QOS, ", transient local"},
        {TRANSIENT_DURABILITY_QOS, ", transient"}, {PERSISTENT_DURABILITY_QOS, ", persistent"}};
    text += durability.at(qos.durability().kind);
    if (qos.history().kind == KEEP_LAST_HISTORY_QOS) {
        text += ", keep last " + std::to_string(qos.history().depth);
    } else {
        text += ", keep all";
    }
    return text;
}

int read(DomainParticipant* participant, const Options& options)
{
    Subscriber* subscriber = participant->create_subscriber(SUBSCRIBER_QOS_DEFAULT);
    DataReaderQos qos = subscriber->get_default_datareader_qos();
    if (options.qos == "rviz2") {
        qos.reliability().kind = RELIABLE_RELIABILITY_QOS;
        qos.durability().kind = VOLATILE_DURABILITY_QOS;
        qos.history().kind = KEEP_LAST_HISTORY_QOS;
        qos.history().depth = 5;
    }
    std::vector<TopicReader> readers;
    std::vector<std::unique_ptr<MatchReporter>> listeners;
    for (const auto& name : options.topics) {
        listeners.push_back(std::make_unique<MatchReporter>(name));
        TopicReader reader;
        reader.topic = name;
        reader.reader = subscriber->create_datareader(create_topic(participant, name), qos, listeners.back().get());
        reader.take_and_print = topic_types().at(name).make_printer(name);
        readers.push_back(std::move(reader));
    }
    print_line("reading " + std::to_string(readers.size()) + " topic(s) with QoS " + options.qos + ": " + describe(qos));
    while (!stop_requested) {
        bool done = options.count > 0;
        for (auto& reader : readers) {
            while ((options.count == 0 || reader.printed < options.count) && reader.take_and_print(reader.reader)) {
                ++reader.printed;
            }
            done = done && reader.printed >= options.count;
        }
        if (done) {
            break;
        }
        readers.front().reader->wait_for_unread_message(eprosima::fastrtps::Duration_t(0, 20000000));
    }
    participant->delete_contained_entities();
    return 0;
}

int write(DomainParticipant* participant, const Options& options)
{
    Publisher* publisher = participant->create_publisher(PUBLISHER_QOS_DEFAULT);
    MatchReporter listener("Circle");
    DataWriterQos qos = publisher->get_default_datawriter_qos();
    DataWriter* writer = publisher->create_datawriter(create_topic(participant, "Circle"), qos, &listener);
    ShapeType shape;
    shape.color(options.color);
    shape.x(options.x);
    shape.y(options.y);
    shape.shapesize(options.size);
    print_line("writing " + json(shape) + " every " + std::to_string(options.period_ms) + " ms with QoS default: " +
               describe(qos));
    for (uint32_t written = 0; !stop_requested && (options.count == 0 || written < options.count); ++written) {
        writer->write(&shape);
        for (uint32_t waited = 0; waited < options.period_ms && !stop_requested; waited += 10) {
            std::this_thread::sleep_for(std::chrono::milliseconds(10));
        }
    }
    participant->delete_contained_entities();
    return 0;
}


// ---- hostile samples ---------------------------------------------------------------------------------------------

using Clock = std::chrono::system_clock;

POSIXTimestamp now_stamp()
{
    auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch()).count();
    POSIXTimestamp stamp;
    stamp.s(static_cast<int32_t>(ns / 1000000000));
    stamp.ns(static_cast<int32_t>(ns % 1000000000));
    return stamp;
}

const float NOT_A_NUMBER = std::nanf("");
const float INFINITE = HUGE_VALF;

// A sample of one hostile kind: its type support (registered under the wire name) and a function making the sample.
struct HostileKind
{
    std::function<TypeSupport()> type_support;
    std::string type_name;  // empty: the type's own name
    std::function<std::shared_ptr<void>()> make;
};

template <typename Sample>
std::function<std::shared_ptr<void>()> maker(std::function<void(Sample&)> spoil)
{
    return [spoil] {
        auto sample = std::make_shared<Sample>();
        spoil(*sample);
        return std::static_pointer_cast<void>(sample);
    };
}

Sensor::SensorObject sensor_object()
{
    Sensor::SensorObject object;
    object.classification(CLASSIFICATION_CAR);
    object.position({1.0f, 2.0f, 0.0f});
    object.velocity({0.5f, 0.0f, 0.0f});
    object.size({4.0f, 1.5f, 1.75f});
    return object;
}

Vision::VisionObject vision_object()
{
    Vision::VisionObject object;
    object.classification(CLASSIFICATION_CAR);
    object.position({1.0f, 2.0f, 0.0f});
    object.velocity({0.5f, 0.0f, 0.0f});
    object.size({4.0f, 1.5f, 1.75f});
    return object;
}

sensor_msgs::msg::dds_::PointField_ point_field(const std::string& name, uint32_t offset)
{
    sensor_msgs::msg::dds_::PointField_ field;
    field.name_(name);
    field.offset_(offset);
    field.datatype_(7);  // FLOAT32
    field.count_(1);
    return field;
}

sensor_msgs::msg::dds_::PointCloud2_ point_cloud(const std::vector<std::string>& names, uint32_t width,
                                                 size_t data_bytes)
{
    sensor_msgs::msg::dds_::PointCloud2_ cloud;
    auto ns = std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch()).count();
    cloud.header_().stamp_().sec_(static_cast<int32_t>(ns / 1000000000));
    cloud.header_().stamp_().nanosec_(static_cast<uint32_t>(ns % 1000000000));
    cloud.header_().frame_id_("map");
    std::vector<sensor_msgs::msg::dds_::PointField_> fields;
    for (size_t i = 0; i < names.size(); ++i) {
        fields.push_back(point_field(names[i], static_cast<uint32_t>(4 * i)));
    }
    cloud.fields_(fields);
    cloud.height_(1);
    cloud.width_(width);
    cloud.point_step_(16);
    cloud.row_step_(16 * width);
    cloud.data_(std::vector<uint8_t>(data_bytes, 0));
    cloud.is_dense_(true);
    return cloud;
}

template <typename Frame>
std::function<std::shared_ptr<void>()> frame_maker()
{
    return maker<Frame>([](Frame& frame) {
        POSIXTimestamp stamp = now_stamp();
        frame.id(1);
        frame.sec_(stamp.s());
        frame.nanosec_(static_cast<uint32_t>(stamp.ns()));
        frame.seqnum(1);
    });
}

const std::map<std::string, std::map<std::string, HostileKind>>& hostile_kinds()
{
    using namespace Platform;
    auto control = [] { return TypeSupport(new PlatformControlPubSubType()); };
    auto status = [] { return TypeSupport(new PlatformStatusPubSubType()); };
    auto objects = [] { return TypeSupport(new Sensor::SensorObjectListPubSubType()); };
    auto vision = [] { return TypeSupport(new Vision::VisionSensorPubSubType()); };
    auto shape = [] { return TypeSupport(new ShapeTypePubSubType()); };
    auto cloud = [] { return TypeSupport(new sensor_msgs::msg::dds_::PointCloud2_PubSubType()); };
    auto control_with = [](std::function<void(PlatformControl&)> spoil) {
        return maker<PlatformControl>([spoil](PlatformControl& c) {
            c.sample_id(1);
            c.timestamp(now_stamp());
            c.speed(1.5f);
            spoil(c);
        });
    };
    auto status_with = [](std::function<void(PlatformStatus&)> spoil) {
        return maker<PlatformStatus>([spoil](PlatformStatus& s) {
            s.timestamp(now_stamp());
            s.vehSpd(50.0f);
            spoil(s);
        });
    };
    auto objects_with = [](std::function<void(Sensor::SensorObjectList&)> spoil) {
        return maker<Sensor::SensorObjectList>([spoil](Sensor::SensorObjectList& l) {
            l.timestamp(now_stamp());
            l.objects({sensor_object()});
            spoil(l);
        });
    };
    auto vision_with = [](std::function<void(Vision::VisionSensor&)> spoil) {
        return maker<Vision::VisionSensor>([spoil](Vision::VisionSensor& v) {
            v.id(66);
            v.timestamp(now_stamp());
            v.objects({vision_object()});
            spoil(v);
        });
    };
    auto shape_with = [](int32_t x, int32_t size) {
        return maker<ShapeType>([x, size](ShapeType& s) {
            s.color("HOSTILE");
            s.x(x);
            s.y(135);
            s.shapesize(size);
        });
    };
    static const std::map<std::string, std::map<std::string, HostileKind>> kinds = {
        {"PlatformControl", {
            {"enum", {control, "", control_with([](PlatformControl& c) {
                c.blinkerStatus(static_cast<IndicatorStatusEnum>(99)); })}},
            {"nan", {control, "", control_with([](PlatformControl& c) { c.speed(NOT_A_NUMBER); })}},
            {"inf", {control, "", control_with([](PlatformControl& c) { c.vehicleSteerAngle(INFINITE); })}},
            {"bad-ns", {control, "", control_with([](PlatformControl& c) { c.timestamp().ns(2000000000); })}},
        }},
        {"PlatformStatus", {
            {"enum", {status, "", status_with([](PlatformStatus& s) {
                s.blinkerStatus(static_cast<IndicatorStatusEnum>(99)); })}},
            {"nan", {status, "", status_with([](PlatformStatus& s) { s.vehSpd(NOT_A_NUMBER); })}},
            {"inf", {status, "", status_with([](PlatformStatus& s) { s.yawRate(-INFINITE); })}},
            {"bad-ns", {status, "", status_with([](PlatformStatus& s) { s.timestamp().ns(-1); })}},
        }},
        {"SensorObjects", {
            {"enum", {objects, "", objects_with([](Sensor::SensorObjectList& l) {
                l.objects()[0].classification(static_cast<ClassificationEnum>(99)); })}},
            {"nan", {objects, "", objects_with([](Sensor::SensorObjectList& l) {
                l.objects()[0].size()[1] = NOT_A_NUMBER; })}},
            {"many", {objects, "", objects_with([](Sensor::SensorObjectList& l) {
                l.objects(std::vector<Sensor::SensorObject>(Sensor::SENSOR_OBJECT_LIST_MAX_SIZE, sensor_object()));
            })}},
            {"empty", {objects, "", objects_with([](Sensor::SensorObjectList& l) { l.objects().clear(); })}},
        }},
        {"VisionTopic", {
            {"enum", {vision, "", vision_with([](Vision::VisionSensor& v) {
                v.objects()[0].classification(static_cast<ClassificationEnum>(99)); })}},
            {"nan", {vision, "", vision_with([](Vision::VisionSensor& v) { v.objects()[0].size()[1] = NOT_A_NUMBER; })}},
            {"many", {vision, "", vision_with([](Vision::VisionSensor& v) {
                v.objects(std::vector<Vision::VisionObject>(Vision::VISION_OBJECT_LIST_MAX_SIZE, vision_object()));
            })}},
            {"empty", {vision, "", vision_with([](Vision::VisionSensor& v) { v.objects().clear(); })}},
        }},
        {"Circle", {
            {"huge", {shape, "", shape_with(120, 2000000000)}},
            {"zero", {shape, "", shape_with(120, 0)}},
            {"negative", {shape, "", shape_with(120, -30)}},
            {"far", {shape, "", shape_with(1000000, 30)}},
        }},
        {"rt/LidarTopic", {
            {"mismatch", {cloud, "", maker<sensor_msgs::msg::dds_::PointCloud2_>(
                [](sensor_msgs::msg::dds_::PointCloud2_& c) { c = point_cloud({"x", "y", "z", "rgb"}, 1000, 16); })}},
            {"noxyz", {cloud, "", maker<sensor_msgs::msg::dds_::PointCloud2_>(
                [](sensor_msgs::msg::dds_::PointCloud2_& c) { c = point_cloud({"i", "j", "k"}, 4, 64); })}},
        }},
        {"CameraImageData", {
            {"short", {[] { return TypeSupport(new Hostile::ShortFramePubSubType()); },
                       "CameraImage::CameraImageData_64KiB", frame_maker<Hostile::ShortFrame>()}},
            {"long", {[] { return TypeSupport(new Hostile::LongFramePubSubType()); },
                      "CameraImage::CameraImageData_64KiB", frame_maker<Hostile::LongFrame>()}},
        }},
    };
    return kinds;
}

int write_hostile(DomainParticipant* participant, const Options& options)
{
    const std::string& topic_name = options.topics[0];
    const auto& kinds = hostile_kinds();
    auto by_topic = kinds.find(topic_name);
    if (by_topic == kinds.end()) {
        usage_error("hostile: no hostile kinds for topic '" + topic_name + "'");
    }
    auto found = by_topic->second.find(options.kind);
    if (found == by_topic->second.end()) {
        std::string known;
        for (const auto& entry : by_topic->second) {
            known += (known.empty() ? "" : ", ") + entry.first;
        }
        usage_error("hostile: unknown kind '" + options.kind + "' for " + topic_name + " (" + known + ")");
    }
    const HostileKind& hostile = found->second;
    TypeSupport type = hostile.type_support();
    if (!hostile.type_name.empty()) {
        type->setName(hostile.type_name.c_str());  // a name-only matcher takes it for the real type
    }
    type.register_type(participant);
    Topic* topic = participant->create_topic(topic_name, type.get_type_name(), TOPIC_QOS_DEFAULT);
    Publisher* publisher = participant->create_publisher(PUBLISHER_QOS_DEFAULT);
    MatchReporter listener(topic_name);
    DataWriterQos qos = publisher->get_default_datawriter_qos();
    qos.deadline().period = eprosima::fastrtps::Duration_t(1, 0);  // our readers request a deadline of 11 s
    DataWriter* writer = publisher->create_datawriter(topic, qos, &listener);
    // Samples written before a reader matched would reach no one: wait for one (60 s at most).
    PublicationMatchedStatus matched;
    for (int waited = 0; !stop_requested && waited < 6000; ++waited) {
        writer->get_publication_matched_status(matched);
        if (matched.current_count > 0) {
            break;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    uint32_t count = options.count;
    print_line("writing " + (count ? std::to_string(count) : std::string("until stopped")) + " hostile sample(s) of"
               " kind " + options.kind + " on " + topic_name + " as " + type.get_type_name());
    uint32_t written = 0;
    for (; !stop_requested && (count == 0 || written < count); ++written) {
        std::shared_ptr<void> sample = hostile.make();
        if (!writer->write(sample.get())) {
            print_line("hostile: write failed");
        }
        for (uint32_t waited = 0; waited < options.period_ms && !stop_requested; waited += 10) {
            std::this_thread::sleep_for(std::chrono::milliseconds(10));
        }
    }
    if (!stop_requested) {
        print_line("hostile: " + std::to_string(written) + " written");
    }
    while (!stop_requested) {  // stay: the test stops it once it has seen what it waits for
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    participant->delete_contained_entities();
    return 0;
}

}  // namespace

int main(int argc, char** argv)
{
    Options options = parse(argc, argv);
    std::signal(SIGINT, on_signal);
    std::signal(SIGTERM, on_signal);
    DomainParticipant* participant = create_participant(options.domain, options.participants, options.socket_buffer,
                                                        options.defaults);
    int code = options.command == "read" ? read(participant, options)
               : options.command == "write" ? write(participant, options) : write_hostile(participant, options);
    DomainParticipantFactory::get_instance()->delete_participant(participant);
    return code;
}
