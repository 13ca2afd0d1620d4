// shape_peer: the other side of the shape_main-compatible command (automotive.tools.shapes.shape_main) on eProsima Fast DDS 2.9, for
// tests/test_shape_main.py. It takes the options of the OMG interoperability suite's shape application that Fast DDS
// 2.9 supports, with their meaning and defaults, and prints the same lines (topic and endpoint creation, matches,
// incompatible QoS, deadlines, one line per sample and per instance that ends).
//
//   shape_peer -P|-S -t TOPIC [-d N] [-c COLOR] [-b|-r] [-k DEPTH] [-f MS] [-s STRENGTH] [-p PARTITION] [-D v|l|t|p]
//              [-x 1] [-w] [-z SIZE] [-R] [--write-period MS] [--read-period MS] [--lifespan MS]
//              [--num-iterations N] [--num-instances N] [--num-topics N] [--final-instance-state u|d]
//              [--additional-payload-size BYTES] [--take-read] [--cft EXPRESSION] [--size-modulo N]
//
// What Fast DDS 2.9 lacks ends with a "... = not supported" line and exit code 2: XCDR2 (-x 2; Fast CDR 1 reads and
// writes XCDR1 only), TRANSIENT and PERSISTENT durability (-D t|p), the time-based filter, the Presentation options. A subscriber's -c and --cft are Fast DDS's
// own content filters (its DDSSQL filter class). Traffic stays on loopback (UDPv4 on 127.0.0.1 only, no shared
// memory, no multicast; initial peer 127.0.0.1 probed for participant ids 0..119). SIGINT/SIGTERM end it cleanly.

#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <fastdds/dds/core/LoanableSequence.hpp>
#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/DataWriterListener.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/DataReaderListener.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/topic/ContentFilteredTopic.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastrtps/utils/IPLocator.h>

#include "shapePubSubTypes.h"
#include "shapeTypeObject.h"

using namespace eprosima::fastdds::dds;

namespace {

constexpr uint32_t MAX_PARTICIPANTS = 120;  // participant ids probed on 127.0.0.1, as the project's Cyclone side
constexpr const char* TYPE_NAME = "ShapeType";

std::atomic<bool> stop_requested{false};
std::mutex output_mutex;

void print_line(const std::string& line)
{
    std::lock_guard<std::mutex> lock(output_mutex);
    std::cout << line << std::endl;
}

[[noreturn]] void usage_error(const std::string& message)
{
    std::cerr << "shape_peer: " << message << std::endl;
    std::exit(2);
}

void on_signal(int) { stop_requested = true; }

struct Options
{
    bool publish = false, subscribe = false;
    uint32_t domain = 0;
    std::string topic, color, partition, cft;
    bool color_set = false, partition_set = false, cft_set = false;
    bool reliable = true;
    char durability = 'v';
    int history_depth = -1;  // -1: Fast DDS's default (KEEP_LAST 1), 0: KEEP_ALL
    int deadline_ms = 0;
    int strength = -1;  // -1: SHARED
    bool xcdr2 = false;
    bool print_writer_samples = false;
    int shapesize = 20;
    bool use_read = false;
    int write_period_ms = 33, read_period_ms = 100, lifespan_ms = 0, time_filter_ms = 0;
    uint32_t num_iterations = 0, num_instances = 1, num_topics = 1, payload = 0;
    int size_modulo = 0;
    char final_state = ' ';
    bool presentation = false;
};

int integer(const std::string& option, const char* text, long minimum)
{
    char* end = nullptr;
    long value = std::strtol(text, &end, 10);
    if (*text == '\0' || *end != '\0' || value < minimum || value > 0x7FFFFFFF) {
        usage_error("option " + option + ": '" + text + "' is not an integer of at least " + std::to_string(minimum));
    }
    return static_cast<int>(value);
}

Options parse(int argc, char** argv)
{
    Options o;
    for (int i = 1; i < argc; ++i) {
        std::string arg = argv[i];
        if (arg == "-P") { o.publish = true; continue; }
        if (arg == "-S") { o.subscribe = true; continue; }
        if (arg == "-b") { o.reliable = false; continue; }
        if (arg == "-r") { o.reliable = true; continue; }
        if (arg == "-w") { o.print_writer_samples = true; continue; }
        if (arg == "-R") { o.use_read = true; continue; }
        if (arg == "--take-read") continue;  // take()/read() is what this peer does anyway
        if (arg == "--coherent" || arg == "--ordered") { o.presentation = true; continue; }
        if (i + 1 >= argc) usage_error("option " + arg + " needs a value");
        const char* value = argv[++i];
        if (arg == "-t") o.topic = value;
        else if (arg == "-d") o.domain = static_cast<uint32_t>(integer(arg, value, 0));
        else if (arg == "-c") { o.color = value; o.color_set = true; }
        else if (arg == "-p") { o.partition = value; o.partition_set = true; }
        else if (arg == "--cft") { o.cft = value; o.cft_set = true; }
        else if (arg == "-k") o.history_depth = integer(arg, value, 0);
        else if (arg == "-f") o.deadline_ms = integer(arg, value, 0);
        else if (arg == "-s") o.strength = integer(arg, value, -1);
        else if (arg == "-D") {
            if (std::strchr("vltp", value[0]) == nullptr || value[0] == '\0') usage_error("-D: expected v, l, t or p");
            o.durability = value[0];
        }
        else if (arg == "-x") {
            if (value[0] != '1' && value[0] != '2') usage_error("-x: expected 1 or 2");
            o.xcdr2 = value[0] == '2';
        }
        else if (arg == "-z") o.shapesize = integer(arg, value, 0);
        else if (arg == "--write-period") o.write_period_ms = integer(arg, value, 0);
        else if (arg == "--read-period") o.read_period_ms = integer(arg, value, 0);
        else if (arg == "--lifespan") o.lifespan_ms = integer(arg, value, 0);
        else if (arg == "--time-filter") o.time_filter_ms = integer(arg, value, 0);
        else if (arg == "--num-iterations") o.num_iterations = static_cast<uint32_t>(integer(arg, value, 1));
        else if (arg == "--num-instances") o.num_instances = static_cast<uint32_t>(integer(arg, value, 1));
        else if (arg == "--num-topics") o.num_topics = static_cast<uint32_t>(integer(arg, value, 1));
        else if (arg == "--additional-payload-size") o.payload = static_cast<uint32_t>(integer(arg, value, 1));
        else if (arg == "--size-modulo") o.size_modulo = integer(arg, value, 1);
        else if (arg == "--final-instance-state") {
            if (value[0] != 'u' && value[0] != 'd') usage_error("--final-instance-state: expected u or d");
            o.final_state = value[0];
        }
        else if (arg == "--access-scope" || arg == "--coherent-sample-count") o.presentation = true;
        else usage_error("unknown option " + arg);
    }
    if (o.topic.empty()) usage_error("please specify topic name [-t]");
    if (o.publish == o.subscribe) usage_error("please specify one of: publish [-P] or subscribe [-S]");
    if (o.subscribe && o.color_set && o.cft_set) usage_error("cannot specify both --cft and -c for subscribers");
    if (o.publish && !o.color_set) o.color = "BLUE";
    return o;
}

DomainParticipant* create_participant(uint32_t domain)
{
    DomainParticipantQos qos = PARTICIPANT_QOS_DEFAULT;
    qos.name("shape_peer");
    auto udp = std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>();
    udp->interfaceWhiteList.push_back("127.0.0.1");
    udp->maxInitialPeersRange = MAX_PARTICIPANTS;
    qos.transport().use_builtin_transports = false;  // no shared memory, no default UDP transport
    qos.transport().user_transports.push_back(udp);
    // Port 0: Fast DDS fills in the well-known port of its participant id. Unicast locators only: no multicast.
    eprosima::fastrtps::rtps::Locator_t loopback;
    eprosima::fastrtps::rtps::IPLocator::setIPv4(loopback, 127, 0, 0, 1);
    qos.wire_protocol().builtin.metatrafficUnicastLocatorList.push_back(loopback);
    qos.wire_protocol().default_unicast_locator_list.push_back(loopback);
    qos.wire_protocol().builtin.initialPeersList.push_back(loopback);
    DomainParticipant* participant = DomainParticipantFactory::get_instance()->create_participant(domain, qos);
    if (participant == nullptr) {
        std::cerr << "shape_peer: cannot create a participant on domain " << domain << std::endl;
        std::exit(1);
    }
    return participant;
}

const char* policy_name(QosPolicyId_t id)
{
    static const std::map<QosPolicyId_t, const char*> names = {
        {DURABILITY_QOS_POLICY_ID, "DURABILITY"}, {PRESENTATION_QOS_POLICY_ID, "PRESENTATION"},
        {DEADLINE_QOS_POLICY_ID, "DEADLINE"}, {OWNERSHIP_QOS_POLICY_ID, "OWNERSHIP"},
        {LIVELINESS_QOS_POLICY_ID, "LIVELINESS"}, {PARTITION_QOS_POLICY_ID, "PARTITION"},
        {RELIABILITY_QOS_POLICY_ID, "RELIABILITY"}, {DESTINATIONORDER_QOS_POLICY_ID, "DESTINATION_ORDER"},
        {DATAREPRESENTATION_QOS_POLICY_ID, "DATA_REPRESENTATION"}};
    auto found = names.find(id);
    return found == names.end() ? "OTHER" : found->second;
}

// Every status event of one endpoint, printed as the suite's reference application prints it.
class ShapeListener : public DataWriterListener, public DataReaderListener
{
public:
    explicit ShapeListener(const std::string& topic) : where_("topic: '" + topic + "'  type: '" + TYPE_NAME + "'") {}

    void on_publication_matched(DataWriter*, const PublicationMatchedStatus& s) override
    {
        print_line("on_publication_matched() " + where_ + " : matched readers " + std::to_string(s.current_count) +
                   " (change = " + std::to_string(s.current_count_change) + ")");
    }
    void on_subscription_matched(DataReader*, const SubscriptionMatchedStatus& s) override
    {
        print_line("on_subscription_matched() " + where_ + " : matched writers " + std::to_string(s.current_count) +
                   " (change = " + std::to_string(s.current_count_change) + ")");
    }
    void on_offered_incompatible_qos(DataWriter*, const OfferedIncompatibleQosStatus& s) override
    {
        print_line("on_offered_incompatible_qos() " + where_ + " : " + std::to_string(s.last_policy_id) + " (" +
                   policy_name(s.last_policy_id) + ")");
    }
    void on_requested_incompatible_qos(DataReader*, const RequestedIncompatibleQosStatus& s) override
    {
        print_line("on_requested_incompatible_qos() " + where_ + " : " + std::to_string(s.last_policy_id) + " (" +
                   policy_name(s.last_policy_id) + ")");
    }
    void on_offered_deadline_missed(DataWriter*, const OfferedDeadlineMissedStatus& s) override
    {
        print_line("on_offered_deadline_missed() " + where_ + " : (total = " + std::to_string(s.total_count) +
                   ", change = " + std::to_string(s.total_count_change) + ")");
    }
    void on_requested_deadline_missed(DataReader*, const RequestedDeadlineMissedStatus& s) override
    {
        print_line("on_requested_deadline_missed() " + where_ + " : (total = " + std::to_string(s.total_count) +
                   ", change = " + std::to_string(s.total_count_change) + ")");
    }
    void on_liveliness_changed(DataReader*, const LivelinessChangedStatus& s) override
    {
        print_line("on_liveliness_changed() " + where_ + " : (alive = " + std::to_string(s.alive_count) +
                   ", not_alive = " + std::to_string(s.not_alive_count) + ")");
    }

private:
    std::string where_;
};

std::string sample_line(const std::string& topic, const ShapeType& shape)
{
    char text[320];
    std::snprintf(text, sizeof text, "%-10s %-10s %03d %03d [%d]", topic.c_str(), shape.color().c_str(), shape.x(),
                  shape.y(), shape.shapesize());
    std::string line = text;
    if (!shape.additional_payload_size().empty()) {
        line += " {" + std::to_string(shape.additional_payload_size().back()) + "}";
    }
    return line;
}

template <typename Qos>
void common_qos(Qos& qos, const Options& o)
{
    qos.reliability().kind = o.reliable ? RELIABLE_RELIABILITY_QOS : BEST_EFFORT_RELIABILITY_QOS;
    static const std::map<char, DurabilityQosPolicyKind> durability = {
        {'v', VOLATILE_DURABILITY_QOS}, {'l', TRANSIENT_LOCAL_DURABILITY_QOS}, {'t', TRANSIENT_DURABILITY_QOS},
        {'p', PERSISTENT_DURABILITY_QOS}};
    qos.durability().kind = durability.at(o.durability);
    qos.ownership().kind = o.strength == -1 ? SHARED_OWNERSHIP_QOS : EXCLUSIVE_OWNERSHIP_QOS;
    if (o.deadline_ms > 0) {
        qos.deadline().period = eprosima::fastrtps::Duration_t(o.deadline_ms / 1000, (o.deadline_ms % 1000) * 1000000u);
    }
    if (o.history_depth > 0) {
        qos.history().kind = KEEP_LAST_HISTORY_QOS;
        qos.history().depth = o.history_depth;
    } else if (o.history_depth == 0) {
        qos.history().kind = KEEP_ALL_HISTORY_QOS;
    }
}

std::vector<Topic*> create_topics(DomainParticipant* participant, const Options& o)
{
    // The type's TypeObject is registered locally, for Fast DDS's SQL content filter, and not sent: Fast DDS 2.9 and
    // Cyclone 11 describe types in different XTypes versions; matched by name only, they interoperate.
    registershapeTypes();
    TypeSupport type(new ShapeTypePubSubType());
    type->auto_fill_type_information(false);
    type->auto_fill_type_object(false);
    type.register_type(participant, TYPE_NAME);
    std::vector<Topic*> topics;
    for (uint32_t i = 0; i < o.num_topics; ++i) {
        std::string name = o.topic + (i > 0 ? std::to_string(i) : "");
        print_line("Create topic: " + name);
        topics.push_back(participant->create_topic(name, TYPE_NAME, TOPIC_QOS_DEFAULT));
    }
    return topics;
}

void sleep_ms(int milliseconds)
{
    auto until = std::chrono::steady_clock::now() + std::chrono::milliseconds(milliseconds);
    while (!stop_requested && std::chrono::steady_clock::now() < until) {
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
}

int publish(DomainParticipant* participant, const Options& o, const std::vector<Topic*>& topics)
{
    PublisherQos publisher_qos = PUBLISHER_QOS_DEFAULT;
    if (o.partition_set) publisher_qos.partition().push_back(o.partition.c_str());
    Publisher* publisher = participant->create_publisher(publisher_qos);
    DataWriterQos qos = publisher->get_default_datawriter_qos();
    common_qos(qos, o);
    if (o.strength != -1) qos.ownership_strength().value = static_cast<uint32_t>(o.strength);
    if (o.lifespan_ms > 0) {
        qos.lifespan().duration = eprosima::fastrtps::Duration_t(o.lifespan_ms / 1000, (o.lifespan_ms % 1000) * 1000000u);
    }
    qos.writer_data_lifecycle().autodispose_unregistered_instances = false;  // unregistering is not disposing
    qos.representation().m_value = {XCDR_DATA_REPRESENTATION};
    std::vector<std::unique_ptr<ShapeListener>> listeners;
    std::vector<DataWriter*> writers;
    for (Topic* topic : topics) {
        print_line("Create writer for topic: " + topic->get_name() + " color: " + o.color);
        listeners.push_back(std::make_unique<ShapeListener>(topic->get_name()));
        writers.push_back(publisher->create_datawriter(topic, qos, listeners.back().get()));
    }
    std::mt19937 random(std::random_device{}());
    ShapeType shape;
    shape.x(static_cast<int32_t>(random() % 240));
    shape.y(static_cast<int32_t>(random() % 270));
    shape.shapesize(o.shapesize);
    shape.additional_payload_size().assign(o.payload, 255);
    int dx = static_cast<int>(random() % 5) + 1, dy = static_cast<int>(random() % 5) + 1;
    for (uint32_t iteration = 0; !stop_requested;) {
        shape.x(shape.x() + dx);
        shape.y(shape.y() + dy);
        if (shape.x() < 0 || shape.x() > 240) { dx = -dx; shape.x(shape.x() < 0 ? 0 : 240); }
        if (shape.y() < 0 || shape.y() > 270) { dy = -dy; shape.y(shape.y() < 0 ? 0 : 270); }
        if (o.shapesize == 0) {
            shape.shapesize(o.size_modulo > 0 ? shape.shapesize() % o.size_modulo + 1 : shape.shapesize() + 1);
        }
        for (DataWriter* writer : writers) {
            for (uint32_t j = 0; j < o.num_instances; ++j) {
                shape.color(o.color + (j > 0 ? std::to_string(j) : ""));
                if (!writer->write(&shape)) std::cerr << "shape_peer: write failed, size " << shape.shapesize() << std::endl;
                if (o.print_writer_samples) print_line(sample_line(writer->get_topic()->get_name(), shape));
            }
        }
        if (o.num_iterations != 0 && ++iteration >= o.num_iterations) break;
        sleep_ms(o.write_period_ms);
    }
    for (DataWriter* writer : writers) {
        for (uint32_t j = 0; j < o.num_instances; ++j) {
            shape.color(o.color + (j > 0 ? std::to_string(j) : ""));
            if (o.final_state == 'd') writer->dispose(&shape, HANDLE_NIL);
            else writer->unregister_instance(&shape, HANDLE_NIL);
        }
        writer->wait_for_acknowledgments(eprosima::fastrtps::Duration_t(1, 0));
    }
    participant->delete_contained_entities();
    return 0;
}

int subscribe(DomainParticipant* participant, const Options& o, const std::vector<Topic*>& topics)
{
    SubscriberQos subscriber_qos = SUBSCRIBER_QOS_DEFAULT;
    if (o.partition_set) subscriber_qos.partition().push_back(o.partition.c_str());
    Subscriber* subscriber = participant->create_subscriber(subscriber_qos);
    DataReaderQos qos = subscriber->get_default_datareader_qos();
    common_qos(qos, o);
    qos.type_consistency().representation.m_value = {XCDR_DATA_REPRESENTATION};
    std::vector<std::unique_ptr<ShapeListener>> listeners;
    std::vector<DataReader*> readers;
    for (Topic* topic : topics) {
        TopicDescription* description = topic;
        if (o.color_set || o.cft_set) {  // Fast DDS's own content filter (DDSSQL)
            std::string expression = o.cft_set ? o.cft : "color = %0";
            std::vector<std::string> parameters;
            if (!o.cft_set) parameters.push_back("'" + o.color + "'");
            description = participant->create_contentfilteredtopic(topic->get_name() + "_filtered", topic,
                                                                   expression, parameters);
            if (description == nullptr) {
                print_line("failed to create content filtered topic");
                return 2;
            }
        }
        print_line("Create reader for topic: " + description->get_name());
        listeners.push_back(std::make_unique<ShapeListener>(topic->get_name()));
        readers.push_back(subscriber->create_datareader(description, qos, listeners.back().get()));
    }
    std::map<InstanceHandle_t, std::string> colors;  // Fast DDS 2.9 gives no key with a disposal
    for (uint32_t iteration = 0; !stop_requested;) {
        for (DataReader* reader : readers) {
            const std::string topic = reader->get_topicdescription()->get_name();
            const std::string name = topic.substr(0, topic.rfind("_filtered") == std::string::npos
                                                          ? topic.size() : topic.rfind("_filtered"));
            FASTDDS_CONST_SEQUENCE(ShapeSeq, ShapeType);
            ShapeSeq samples;
            SampleInfoSeq infos;
            ReturnCode_t result = o.use_read ? reader->read(samples, infos) : reader->take(samples, infos);
            if (result != ReturnCode_t::RETCODE_OK) continue;
            for (LoanableCollection::size_type i = 0; i < samples.length(); ++i) {
                const SampleInfo& info = infos[i];
                if (info.valid_data) {
                    print_line(sample_line(name, samples[i]));
                    colors[info.instance_handle] = samples[i].color().c_str();
                }
                if (info.instance_state == NOT_ALIVE_DISPOSED_INSTANCE_STATE ||
                    info.instance_state == NOT_ALIVE_NO_WRITERS_INSTANCE_STATE) {
                    char text[320];
                    std::snprintf(text, sizeof text, "%-10s %-10s %s", name.c_str(),
                                  colors[info.instance_handle].c_str(),
                                  info.instance_state == NOT_ALIVE_DISPOSED_INSTANCE_STATE
                                      ? "NOT_ALIVE_DISPOSED_INSTANCE_STATE" : "NOT_ALIVE_NO_WRITERS_INSTANCE_STATE");
                    print_line(text);
                }
            }
            reader->return_loan(samples, infos);
        }
        if (o.num_iterations != 0 && ++iteration >= o.num_iterations) break;
        sleep_ms(o.read_period_ms);
    }
    participant->delete_contained_entities();
    return 0;
}

}  // namespace

int main(int argc, char** argv)
{
    Options o = parse(argc, argv);
    std::signal(SIGINT, on_signal);
    std::signal(SIGTERM, on_signal);
    DomainParticipant* participant = create_participant(o.domain);
    std::vector<Topic*> topics = create_topics(participant, o);
    // Fast DDS 2.9: Fast CDR 1 has no XCDR2; TRANSIENT needs a persistence service, PERSISTENT is refused.
    const char* unsupported = o.xcdr2 ? "    DataRepresentation = XCDR2 : not supported"
                              : o.presentation ? "    Presentation Coherent Access = not supported"
                              : o.durability == 't' ? "    Durability = TRANSIENT_DURABILITY_QOS : not supported"
                              : o.durability == 'p' ? "    Durability = PERSISTENT_DURABILITY_QOS : not supported"
                              : (o.subscribe && o.time_filter_ms > 0) ? "    TimeBasedFilter = not supported" : nullptr;
    int code = 2;
    if (unsupported != nullptr) {
        print_line(unsupported);
        participant->delete_contained_entities();
    } else {
        code = o.publish ? publish(participant, o, topics) : subscribe(participant, o, topics);
    }
    DomainParticipantFactory::get_instance()->delete_participant(participant);
    if (code == 0) print_line("Done.");
    return code;
}
