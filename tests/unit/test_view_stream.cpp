// svo serve's view stream (svo/store/view_stream.hpp, server/src/stream_session.cpp,
// client/stream_source.hpp) against independent references: hand-decoded frame bytes, the scheduler's own
// order and the budget summed by hand, the frame a local pager converges to bit for bit, and a WebSocket
// client of the tests' own (Beast) that sends what a real client never would. The server listens on
// 127.0.0.1; every read is bounded in time.
#include <gtest/gtest.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <optional>
#include <thread>

#include <unistd.h>

#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core/buffers_to_string.hpp>
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/websocket/stream.hpp>
#include <nlohmann/json.hpp>

#include "paging_helpers.hpp"
#include "reference.hpp"
#include "server_client.hpp"
#include "svo/client/locator.hpp"
#include "svo/client/stream_source.hpp"
#include "svo/server/server.hpp"
#include "svo/store/store_reader.hpp"
#include "svo/store/view_stream.hpp"

namespace fs = std::filesystem;
namespace beast = boost::beast;
namespace net = boost::asio;
namespace websocket = beast::websocket;
namespace stream = svo::stream;
using svotest::sphereStore;

namespace {

constexpr auto kReadTimeout = std::chrono::seconds(10);

// One WebSocket to the test server, driven synchronously through bounded runs of its own I/O context.
class WsClient {
 public:
  struct Message {
    bool binary = false;
    std::string bytes;
  };
  // Connects and asks for the upgrade of `target`; the server's answer status (101 when accepted).
  unsigned open(std::uint16_t port, const std::string& target, const std::string& token = "") {
    ws_.emplace(io_);
    beast::get_lowest_layer(*ws_).connect(net::ip::tcp::endpoint(net::ip::make_address("127.0.0.1"), port));
    ws_->set_option(websocket::stream_base::decorator([token](websocket::request_type& req) {
      if (!token.empty()) req.set(beast::http::field::authorization, "Bearer " + token);
    }));
    websocket::response_type answer;
    ws_->async_handshake(answer, "127.0.0.1", target, [](beast::error_code) {});
    run();
    return answer.result_int();
  }
  // False when the server closed the connection before taking it all (as it does a message too large).
  bool send(const std::string& text, bool binary = false) {
    ws_->binary(binary);
    beast::error_code ec;
    ws_->write(net::buffer(text), ec);
    return !ec;
  }
  // The next message; nothing when the stream closed (closeReason() then says how).
  std::optional<Message> read() {
    beast::flat_buffer buffer;
    beast::error_code result;
    ws_->async_read(buffer, [&](beast::error_code ec, std::size_t) { result = ec; });
    run();
    if (result) return std::nullopt;
    return Message{ws_->got_binary(), beast::buffers_to_string(buffer.data())};
  }
  const websocket::close_reason& closeReason() const { return ws_->reason(); }
  // Drops the connection without a close handshake, as a client that vanishes.
  void vanish() { beast::get_lowest_layer(*ws_).socket().close(); }

 private:
  // Runs the operation just started to its end, within kReadTimeout.
  void run() {
    io_.restart();
    io_.run_for(kReadTimeout);
    if (!io_.stopped()) {
      ADD_FAILURE() << "no answer within " << kReadTimeout.count() << " s";
      beast::get_lowest_layer(*ws_).socket().close();
      io_.restart();
      io_.run();
    }
  }
  net::io_context io_;
  std::optional<websocket::stream<beast::tcp_stream>> ws_;
};

class ViewStream : public svotest::ServedFolder {
 protected:
  void stopServer() override { server_.reset(); }
  void start(std::uint64_t windowBytes = svo::server::kDefaultStreamWindowBytes,
             const std::string& token = "") {
    server_ = svotest::startServer(root_, 0, token, windowBytes);
  }
  std::uint16_t port() const { return server_->port(); }
  std::string url() const { return server_->url() + "/scene"; }
  double metric(const std::string& name) const {
    const std::string text = svotest::httpGet(port(), "/metrics").body;
    const std::size_t at = text.find("\n" + name + " ");
    return at == std::string::npos ? -1.0 : std::stod(text.substr(at + name.size() + 2));
  }

  std::unique_ptr<svo::server::Server> server_;
};

// A view of the whole store: every slice wanted, the budget ample.
stream::View wholeView(std::uint64_t id, glm::dvec3 eye = {1.5, 1.5, 4.0}) {
  stream::View v;
  v.id = id;
  v.query.eye = eye;
  v.query.pixelAngle = 1e-3;
  v.query.lodPixels = 1e-9;
  v.budgetBytes = std::uint64_t(1) << 30;
  return v;
}

}  // namespace

// The slice frame's head, decoded by hand: "SVSL", slice 5 and view 0x0102030405060708, little-endian.
TEST(ViewStreamProtocol, SliceFrameHeaderHasItsDocumentedBytes) {
  const unsigned char fixture[16] = {0x53, 0x56, 0x53, 0x4C, 0x05, 0x00, 0x00, 0x00,
                                     0x08, 0x07, 0x06, 0x05, 0x04, 0x03, 0x02, 0x01};
  std::array<std::byte, 16> written{};
  stream::writeSliceFrameHeader({5, 0x0102030405060708ull}, written);
  EXPECT_EQ(std::memcmp(written.data(), fixture, 16), 0);
  const auto* bytes = reinterpret_cast<const std::byte*>(fixture);
  const stream::SliceFrameHeader read = stream::readSliceFrameHeader(std::span(bytes, 16));
  EXPECT_EQ(read.slice, 5u);
  EXPECT_EQ(read.view, 0x0102030405060708ull);
  EXPECT_THROW(stream::readSliceFrameHeader(std::span(bytes, 15)), stream::ProtocolError);
  std::array<std::byte, 16> wrong = written;
  wrong[0] = std::byte{0};
  EXPECT_THROW(stream::readSliceFrameHeader(wrong), stream::ProtocolError);
}

TEST(ViewStreamProtocol, ViewsRoundTripAndBadFieldsAreNamed) {
  stream::View v = wholeView(7, {1.25, -3.5, 1e6});
  v.query.frustum = {{1, 0, 0, 1.5}, {0, -1, 0, -2}};
  v.query.outsideWeight = 0.25;
  v.held = {3, 1, 4};
  v.first = {9, 2};
  const stream::ClientMessage m = stream::parseClientMessage(stream::encodeView(v), 10);
  ASSERT_EQ(m.kind, stream::ClientMessage::Kind::View);
  EXPECT_EQ(m.view.id, 7u);
  EXPECT_EQ(m.view.query.eye, v.query.eye);
  EXPECT_EQ(m.view.query.frustum, v.query.frustum);
  EXPECT_EQ(m.view.query.outsideWeight, 0.25);
  EXPECT_EQ(m.view.budgetBytes, v.budgetBytes);
  EXPECT_EQ(m.view.held, v.held);
  EXPECT_EQ(m.view.first, v.first);
  EXPECT_EQ(stream::parseClientMessage(stream::encodeAck(12345), 10).ackedBytes, 12345u);
  const std::vector<std::uint32_t> wanted = {9, 0};
  EXPECT_EQ(stream::parseClientMessage(stream::encodeWant(wanted), 10).wanted, wanted);

  const std::string good = stream::encodeView(wholeView(1));
  const auto errorOf = [](const std::string& text, std::size_t slices = 10) {
    try {
      stream::parseClientMessage(text, slices);
    } catch (const stream::ProtocolError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  const auto with = [&](const std::string& field, const std::string& value) {
    nlohmann::json j = nlohmann::json::parse(good);
    j[field] = nlohmann::json::parse(value);
    return j.dump();
  };
  EXPECT_EQ(errorOf("{\"view\":1,"), "not JSON");
  EXPECT_EQ(errorOf("[1,2]"), "not a JSON object");
  EXPECT_EQ(errorOf(R"({"view":1,"eye":[NaN,0,0]})"), "not JSON");    // JSON has no NaN
  EXPECT_EQ(errorOf(R"({"view":1,"eye":[1e999,0,0]})"), "not JSON");  // nor infinities
  EXPECT_EQ(errorOf(with("eye", "[1e13,0,0]")), "eye: farther than 1e12 from the scene");
  EXPECT_EQ(errorOf(with("eye", "[1,2]")), "eye: not an array of 3 numbers");
  EXPECT_EQ(errorOf(with("eye", "[\"1\",2,3]")), "eye: not a number");
  EXPECT_NE(errorOf(with("pixelAngle", "0")).find("pixelAngle: 0.000000 is outside"), std::string::npos);
  EXPECT_NE(errorOf(with("lodPixels", "-1")).find("lodPixels: -1.000000 is outside"), std::string::npos);
  EXPECT_EQ(errorOf(with("budget", "0")), "budget: 0 bytes is not in [1, 2^40]");
  EXPECT_EQ(errorOf(with("budget", "1099511627777")), "budget: 1099511627777 bytes is not in [1, 2^40]");
  EXPECT_EQ(errorOf(with("budget", "-5")), "budget: not a non-negative integer");
  EXPECT_EQ(errorOf(with("view", "1.5")), "view: not a non-negative integer");
  EXPECT_NE(errorOf(with("held", "[10]")).find("held: 10 is not a slice of this store"), std::string::npos);
  EXPECT_NE(errorOf(R"({"want":[3,10]})").find("want: 10 is not a slice of this store"), std::string::npos);
  EXPECT_EQ(errorOf(with("frustum", "[[1,0,0]]")), "frustum: a plane is not 4 numbers");
  EXPECT_EQ(errorOf(with("frustum", nlohmann::json(std::vector<std::array<int, 4>>(17)).dump())),
            "frustum: more than 16 planes");
  nlohmann::json noEye = nlohmann::json::parse(good);
  noEye.erase("eye");
  EXPECT_EQ(errorOf(noEye.dump()), "no \"eye\" field");
  EXPECT_EQ(errorOf(std::string(stream::maxClientMessageBytes(10) + 1, ' ')), "message too large");
}

// The plan is the scheduler's slices, cut where the decoded bytes summed here would pass the budget, in its
// order but for each cube's chain, which comes in one run after its first slice.
TEST(ViewStreamPlan, PlanIsTheScheduleWithinTheBudget) {
  const svo::StoreReader store(sphereStore());
  const svo::StoreIndex& index = store.index();
  const stream::View view = wholeView(1, {1.7, 1.2, 1.9});
  const std::vector<svo::SliceRequest> wanted = svo::scheduleSlices(index, view.query);
  ASSERT_GT(wanted.size(), 10u);
  std::uint64_t half = 0;
  for (std::size_t k = 0; k < wanted.size() / 2; ++k) half += index.slices()[wanted[k].slice].rawBytes;
  for (const std::uint64_t budget : {half, half - 1, std::uint64_t(1) << 40, std::uint64_t(1)}) {
    const std::vector<std::uint32_t> plan = stream::planSlices(index, view.query, budget);
    std::uint64_t sum = 0;
    std::size_t fit = 0;
    while (fit < wanted.size() && sum + index.slices()[wanted[fit].slice].rawBytes <= budget)
      sum += index.slices()[wanted[fit++].slice].rawBytes;
    ASSERT_EQ(plan.size(), fit) << budget;
    std::vector<std::uint32_t> expected, got = plan;
    for (std::size_t k = 0; k < fit; ++k) expected.push_back(wanted[k].slice);
    std::sort(expected.begin(), expected.end());
    std::sort(got.begin(), got.end());
    EXPECT_EQ(got, expected) << "the schedule's slices within the budget";
    std::vector<std::size_t> at(index.slices().size(), SIZE_MAX);
    for (std::size_t k = 0; k < plan.size(); ++k) at[plan[k]] = k;
    for (std::size_t k = 0; k < plan.size(); ++k) {
      const svo::SliceInfo& s = index.slices()[plan[k]];
      if (s.parentSlice == svo::SliceInfo::kNoSlice || at[s.parentSlice] == SIZE_MAX) continue;
      EXPECT_LT(at[s.parentSlice], k) << "a slice after its parents";
      const svo::SliceInfo& p = index.slices()[s.parentSlice];
      if (p.cubeLevel == s.cubeLevel && p.cubeCoord == s.cubeCoord && p.firstSlot == s.firstSlot &&
          p.lastSlot == s.lastSlot)
        EXPECT_EQ(at[s.parentSlice] + 1, k) << "a cube's chain in one run";
    }
    // Chain heads keep the schedule's order.
    std::vector<std::uint32_t> heads;
    for (const std::uint32_t slice : plan) {
      const svo::SliceInfo& s = index.slices()[slice];
      const bool continues = s.parentSlice != svo::SliceInfo::kNoSlice && at[s.parentSlice] != SIZE_MAX &&
                             index.slices()[s.parentSlice].cubeLevel == s.cubeLevel &&
                             index.slices()[s.parentSlice].cubeCoord == s.cubeCoord &&
                             index.slices()[s.parentSlice].firstSlot == s.firstSlot &&
                             index.slices()[s.parentSlice].lastSlot == s.lastSlot;
      if (!continues) heads.push_back(slice);
    }
    std::size_t next = 0;
    for (std::size_t k = 0; k < fit && next < heads.size(); ++k)
      if (wanted[k].slice == heads[next]) ++next;
    EXPECT_EQ(next, heads.size()) << "chain heads in the schedule's order";
  }
}

// The pager fed by the view stream converges to the local pager's frame bit for bit, and its slices came
// pushed, not requested.
TEST_F(ViewStream, PagerConvergesToTheLocalFrameFromPushedSlices) {
  start();
  const std::shared_ptr<svo::SliceSource> source = svo::openSliceSource(url(), svotest::quickRetries());
  const auto* streamed = dynamic_cast<const svo::ViewStreamSource*>(source.get());
  ASSERT_NE(streamed, nullptr);
  svo::PagerOptions options;
  options.fetchThreads = 4;
  svo::Pager local(sphereStore(), options), served(source, options);
  const svo::Camera camera = svotest::cameraAt({1.6, 2.4, 3.0}, {0, 0, 0}, 96);
  const svo::ViewQuery view = svo::viewOf(local.transform(), camera, 0.0);
  for (int i = 0; i < 500 && !streamed->streaming(); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  ASSERT_TRUE(streamed->streaming());
  svotest::converge(local, view);
  svotest::converge(served, view);
  EXPECT_TRUE(served.failedSlices().empty());
  EXPECT_EQ(served.residentSlices(), local.residentSlices());
  served.checkInvariants();
  svotest::expectSameFrame(svotest::renderFinest(served, camera), svotest::renderFinest(local, camera));
  const svo::StreamStats stats = streamed->stats();
  EXPECT_FALSE(stats.declined);
  EXPECT_GE(stats.viewsSent, 1u);
  EXPECT_GT(stats.usedPushed, served.residentSlices().size() / 2) << "most slices came pushed";
  EXPECT_EQ(metric("svo_streams_open"), 1.0);
  EXPECT_GE(metric("svo_stream_view_updates_total"), 1.0);
  EXPECT_GE(metric("svo_stream_slices_sent_total"), double(stats.usedPushed));
}

// With a window of one byte the server sends one slice and waits for its acknowledgement; a new view then
// drops the rest of the old plan, and the new plan leaves out the slice already sent.
TEST_F(ViewStream, NewViewSupersedesThePlanAndNothingIsSentTwice) {
  start(/*windowBytes=*/1);
  const svo::StoreReader store(sphereStore());
  WsClient ws;
  ASSERT_EQ(ws.open(port(), "/scene/stream"), 101u);
  ws.send(stream::encodeView(wholeView(1)));
  const auto plan1 = ws.read();
  ASSERT_TRUE(plan1 && !plan1->binary);
  const stream::ServerMessage first = stream::parseServerMessage(plan1->bytes, store.slices().size());
  ASSERT_EQ(first.view, 1u);
  EXPECT_EQ(first.plan, stream::planSlices(store.index(), wholeView(1).query, wholeView(1).budgetBytes));
  const auto frame = ws.read();
  ASSERT_TRUE(frame && frame->binary);
  const auto* bytes = reinterpret_cast<const std::byte*>(frame->bytes.data());
  const stream::SliceFrameHeader head = stream::readSliceFrameHeader(std::span(bytes, frame->bytes.size()));
  EXPECT_EQ(head.slice, first.plan.front());
  EXPECT_EQ(head.view, 1u);
  // The bytes as stored: the store's own check passes.
  svo::SliceBytes slice(bytes + stream::kSliceFrameHeaderBytes, bytes + frame->bytes.size());
  EXPECT_NO_THROW(svo::checkSlice(store.index(), head.slice, slice));

  ws.send(stream::encodeView(wholeView(2, {1.5, 4.0, 1.5})));  // no ack: the window stays full
  const auto plan2 = ws.read();
  ASSERT_TRUE(plan2 && !plan2->binary);
  const stream::ServerMessage second = stream::parseServerMessage(plan2->bytes, store.slices().size());
  EXPECT_EQ(second.view, 2u);
  EXPECT_EQ(second.plan.size(), first.plan.size() - 1) << "the same slices, less the one sent";
  EXPECT_EQ(std::find(second.plan.begin(), second.plan.end(), head.slice), second.plan.end());
  EXPECT_EQ(metric("svo_stream_superseded_slices_total"), double(first.plan.size() - 1));
  ws.send(stream::encodeAck(frame->bytes.size()));
  const auto next = ws.read();
  ASSERT_TRUE(next && next->binary);
  const auto* nextBytes = reinterpret_cast<const std::byte*>(next->bytes.data());
  EXPECT_EQ(stream::readSliceFrameHeader(std::span(nextBytes, next->bytes.size())).view, 2u);
}

// A slice a fetch waits for goes before the rest of the plan: the pager's order, feedback included, wins.
TEST_F(ViewStream, WantedSlicesAreSentNext) {
  start(/*windowBytes=*/1);
  const svo::StoreReader store(sphereStore());
  WsClient ws;
  ASSERT_EQ(ws.open(port(), "/scene/stream"), 101u);
  ws.send(stream::encodeView(wholeView(1)));
  const auto planMessage = ws.read();
  ASSERT_TRUE(planMessage);
  const std::vector<std::uint32_t> plan =
      stream::parseServerMessage(planMessage->bytes, store.slices().size()).plan;
  ASSERT_GT(plan.size(), 3u);
  std::uint64_t received = 0;
  const auto nextSlice = [&] {
    const auto frame = ws.read();
    EXPECT_TRUE(frame && frame->binary);
    if (!frame) return std::uint32_t(-1);
    received += frame->bytes.size();
    const auto* bytes = reinterpret_cast<const std::byte*>(frame->bytes.data());
    return stream::readSliceFrameHeader(std::span(bytes, frame->bytes.size())).slice;
  };
  EXPECT_EQ(nextSlice(), plan[0]);  // the window holds the rest back until the ack
  const std::vector<std::uint32_t> wanted = {plan.back(), plan[plan.size() - 2]};
  ws.send(stream::encodeWant(wanted));
  ws.send(stream::encodeAck(received));
  EXPECT_EQ(nextSlice(), wanted[0]);
  ws.send(stream::encodeAck(received));
  EXPECT_EQ(nextSlice(), wanted[1]);
  ws.send(stream::encodeAck(received));
  EXPECT_EQ(nextSlice(), plan[1]) << "then the plan's order again";

  // A view's own `first` leads its plan.
  stream::View view = wholeView(2, {1.5, 4.0, 1.5});
  std::vector<std::uint32_t> unsent;  // view 2's plan less the four slices sent
  for (const std::uint32_t s : stream::planSlices(store.index(), view.query, view.budgetBytes))
    if (s != plan[0] && s != plan[1] && s != wanted[0] && s != wanted[1]) unsent.push_back(s);
  ASSERT_GE(unsent.size(), 3u);
  view.first = {unsent.back(), unsent[unsent.size() - 2]};
  ws.send(stream::encodeView(view));
  const auto second = ws.read();
  ASSERT_TRUE(second && !second->binary);
  const std::vector<std::uint32_t> sent =
      stream::parseServerMessage(second->bytes, store.slices().size()).plan;
  ASSERT_GE(sent.size(), 2u);
  EXPECT_EQ(sent[0], view.first[0]);
  EXPECT_EQ(sent[1], view.first[1]);
  ws.send(stream::encodeAck(received));
  EXPECT_EQ(nextSlice(), view.first[0]);
}

// Each bad message closes its own stream with a reason naming what is wrong; the server serves on.
TEST_F(ViewStream, BadMessagesCloseTheirStreamAndTheServerServesOn) {
  start();
  const std::string good = stream::encodeView(wholeView(1));
  struct Case {
    std::string message;
    bool binary;
    websocket::close_code code;
    std::string reason;
  };
  const std::vector<Case> cases = {
      {"{\"view\":", false, websocket::close_code::policy_error, "bad message: not JSON"},
      {"{\"view\":1,\"eye\":[1e999,0,0]}", false, websocket::close_code::policy_error,
       "bad message: not JSON"},
      {"{\"view\":1,\"eye\":[1,2,3]}", false, websocket::close_code::policy_error,
       "bad message: no \"pixelAngle\" field"},
      {good.substr(0, good.find("\"budget\":")) + "\"budget\":0" +
           good.substr(good.find(',', good.find("\"budget\":"))),
       false, websocket::close_code::policy_error, "bad message: budget: 0 bytes is not in [1, 2^40]"},
      {stream::encodeAck(5), false, websocket::close_code::policy_error,
       "bad message: ack of 5 bytes, 0 sent"},
      {"\x01\x02", true, websocket::close_code::bad_payload,
       "a binary message: the view stream takes JSON text"},
      {std::string(1 << 20, '['), false, websocket::close_code::too_big, ""},
  };
  for (const Case& c : cases) {
    WsClient ws;
    ASSERT_EQ(ws.open(port(), "/scene/stream"), 101u);
    const bool sent = ws.send(c.message, c.binary);
    while (ws.read()) {
    }
    // A message too large is refused while the client still sends it: its close frame may be lost to the
    // reset that closing with unread bytes causes.
    if (sent || c.code != websocket::close_code::too_big) {
      EXPECT_EQ(ws.closeReason().code, c.code) << c.reason;
      EXPECT_EQ(std::string(ws.closeReason().reason.c_str()), c.reason);
    }
    EXPECT_EQ(svotest::httpGet(port(), "/healthz").status, 200u);
  }
  // A view whose id does not grow.
  WsClient ws;
  ASSERT_EQ(ws.open(port(), "/scene/stream"), 101u);
  ws.send(stream::encodeView(wholeView(3)));
  ws.send(stream::encodeView(wholeView(3)));
  while (ws.read()) {
  }
  EXPECT_EQ(std::string(ws.closeReason().reason.c_str()), "bad message: view 3 after view 3");
}

// The upgrade is a request like any other: unknown scenes, traversal, missing and wrong tokens are answered
// as such before any stream opens, and a plain GET learns that the route is a WebSocket.
TEST_F(ViewStream, UpgradeRequestsAreCheckedLikeAnyRequest) {
  start(svo::server::kDefaultStreamWindowBytes, "secret");
  EXPECT_EQ(WsClient().open(port(), "/scene/stream"), 401u);
  EXPECT_EQ(WsClient().open(port(), "/scene/stream", "wrong"), 403u);
  EXPECT_EQ(WsClient().open(port(), "/nothing/stream", "secret"), 404u);
  EXPECT_EQ(WsClient().open(port(), "/%2E%2E/scene/stream", "secret"), 400u);
  EXPECT_EQ(WsClient().open(port(), "/scene/stream", "secret"), 101u);
  const svotest::HttpReply plain =
      svotest::httpGet(port(), "/scene/stream", {{"Authorization", "Bearer secret"}});
  EXPECT_EQ(plain.status, 426u);
  EXPECT_EQ(plain.header("upgrade"), "websocket");
}

// A client that vanishes mid-stream costs the others nothing: its stream ends, theirs go on.
TEST_F(ViewStream, ClientsThatVanishMidStreamLeaveTheOthersServed) {
  start(/*windowBytes=*/1);
  const svo::StoreReader store(sphereStore());
  {
    WsClient gone;
    ASSERT_EQ(gone.open(port(), "/scene/stream"), 101u);
    gone.send(stream::encodeView(wholeView(1)));
    ASSERT_TRUE(gone.read());  // its plan; a slice waits for an ack that never comes
    gone.vanish();
  }
  WsClient ws;
  ASSERT_EQ(ws.open(port(), "/scene/stream"), 101u);
  ws.send(stream::encodeView(wholeView(1)));
  const auto plan = ws.read();
  ASSERT_TRUE(plan);
  const stream::ServerMessage m = stream::parseServerMessage(plan->bytes, store.slices().size());
  std::uint64_t received = 0;
  for (std::size_t k = 0; k < m.plan.size(); ++k) {
    const auto frame = ws.read();
    ASSERT_TRUE(frame && frame->binary) << k;
    received += frame->bytes.size();
    ws.send(stream::encodeAck(received));
  }
  for (int i = 0; i < 200 && metric("svo_streams_open") != 1.0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  EXPECT_EQ(metric("svo_streams_open"), 1.0) << "the vanished client's stream ended";
}

// A slice corrupt on disk: the stream says which one it cannot send, in a message of its own, and goes on
// with the rest of the plan.
TEST_F(ViewStream, CorruptSliceIsNamedAndTheRestIsSent) {
  const svo::StoreReader store(sphereStore());
  const std::uint32_t bad = 5;
  {
    std::fstream file(root_ / "scene.svo", std::ios::in | std::ios::out | std::ios::binary);
    file.seekp(std::streamoff(store.slices()[bad].offset + 3));
    file.put('\x5a' ^ char(file.peek()));
  }
  start();
  WsClient ws;
  ASSERT_EQ(ws.open(port(), "/scene/stream"), 101u);
  ws.send(stream::encodeView(wholeView(1)));
  const auto planMessage = ws.read();
  ASSERT_TRUE(planMessage);
  const stream::ServerMessage plan = stream::parseServerMessage(planMessage->bytes, store.slices().size());
  ASSERT_NE(std::find(plan.plan.begin(), plan.plan.end(), bad), plan.plan.end());
  std::size_t slices = 0, errors = 0;
  for (std::size_t k = 0; k < plan.plan.size(); ++k) {
    const auto m = ws.read();
    ASSERT_TRUE(m) << k;
    if (m->binary) {
      ++slices;
      continue;
    }
    const stream::ServerMessage error = stream::parseServerMessage(m->bytes, store.slices().size());
    ASSERT_EQ(error.kind, stream::ServerMessage::Kind::SliceError);
    EXPECT_EQ(error.slice, bad);
    EXPECT_NE(error.error.find("scene: "), std::string::npos) << error.error;  // named by scene, not path
    EXPECT_EQ(error.error.find(root_.string()), std::string::npos) << error.error;
    ++errors;
  }
  EXPECT_EQ(errors, 1u);
  EXPECT_EQ(slices, plan.plan.size() - 1);
  EXPECT_EQ(metric("svo_corrupt_slices_total"), 1.0);
}

// The server stops while upgrades are in flight: a stream whose handshake is still being answered closes
// after it (Beast allows no other operation on the stream during it), and the server stops.
TEST_F(ViewStream, ServerStopsWhileUpgradesAreInFlight) {
  const std::string upgrade =
      "GET /scene/stream HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
      "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n";
  // Rounds, each stopping a little later after the upgrades were sent.
  constexpr int kRounds = 100;
  for (int round = 0; round < kRounds; ++round) {
    start();
    std::vector<int> sockets;
    for (int c = 0; c < 8; ++c) {
      sockets.push_back(svotest::connectRaw(port()));
      ASSERT_TRUE(svotest::sendRaw(sockets.back(), upgrade));
    }
    std::this_thread::sleep_for(std::chrono::microseconds(25 * (round % 20)));
    std::thread stopping([&] { stopServer(); });
    // The clients go without answering the close, so that the server need not wait out its grace.
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
    for (const int fd : sockets) ::close(fd);
    stopping.join();
  }
}
