// `esg alerts [--spacecraft ID] [--since T] [--active] [--severity MIN] [--include-revised]
// [--follow] [--ack SEQ] [--operator NAME]`: the alerts
// raised by the fault and innovation tests (eq. (12), (14)) and by rejected telemetry
// (SubscribeAlerts), and their acknowledgement (AcknowledgeAlert).
//
// Listing: subscribes with `since` (default: every stored alert) and the end-of-replay marker
// (AlertSubscription.replay_marker) and prints the latest state of each alert once the marker
// arrives: the stored alerts are then complete, whatever their number and the network's speed.
// --follow prints the stored alerts, then keeps printing alert states as they arrive (one line,
// or with --format json one JSON object per line, with --format csv a header then one row per
// alert state) until Ctrl-C.
// --active keeps the alerts not cleared (nor revised); --severity MIN those of severity MIN or
// worse (INFO < WARNING < DISTRESS < CRITICAL, the order of AlertSeverity). Both filter here, in
// the client, every format and --follow alike.
// --include-revised also lists the alerts a re-run over a late frame superseded ("revised at").
// --ack SEQ acknowledges alert SEQ of --spacecraft as --operator and prints it; without
// --operator the name is the token's (the service takes it from --token / $ESG_TOKEN), or $USER
// when no token is given.
// The table line is a sentence: "RDK-1 #3 WARNING star tracker innovation on star_tracker:
// 412.3 arcsec, above the threshold 150 arcsec, 2 times from T1 to T2[, acknowledged by NAME at
// T][, cleared at T]: <message>" ("above" or "below" as the numbers are; no unit for a
// dimensionless value).
// Exit codes: 0 success (also when stopped by Ctrl-C), 2 bad arguments, 1 server failure.
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <csignal>
#include <cstdio>
#include <deque>
#include <iostream>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/commands/commands.h"
#include "client/commands/server_common.h"
#include "proto/convert.h"

namespace esg::client {
namespace {

constexpr char kVerb[] = "alerts";

struct AlertsOptions {
  std::string spacecraft_id;
  std::string since;
  bool include_revised = false;
  bool active_only = false;
  std::string min_severity;  // empty: every severity
  bool follow = false;
  std::optional<int64_t> ack;
  std::string operator_name;
  OutputFormat format = OutputFormat::kTable;
};

volatile std::sig_atomic_t g_interrupted = 0;
extern "C" void OnInterrupt(int) { g_interrupted = 1; }

// "25.3 arcsec" or, for a dimensionless value (unit "1" or none), "25.3".
std::string WithUnit(double value, const std::string& unit) {
  return unit.empty() || unit == "1" ? absl::StrFormat("%.6g", value)
                                     : absl::StrFormat("%.6g %s", value, unit);
}

std::string AlertLine(const esg::v1::Alert& a) {
  const char* side = a.value() > a.threshold()   ? "above"
                     : a.value() < a.threshold() ? "below"
                                                 : "at";
  const std::string first = FormatUtc(a.first_time(), a.has_first_time());
  const std::string latest = FormatUtc(a.measurement_time(), a.has_measurement_time());
  const std::string when =
      a.repeat_count() <= 1
          ? absl::StrCat("once at ", latest)
          : absl::StrCat(a.repeat_count(), " times from ", first, " to ", latest);
  std::string line = absl::StrFormat(
      "%s #%d %s %s on %s: %s, %s the threshold %s, %s", a.spacecraft_id(), a.sequence(),
      SeverityName(a.severity()), ReasonWords(a.reason()), a.subsystem(),
      WithUnit(a.value(), a.unit()), side, WithUnit(a.threshold(), a.unit()), when);
  if (a.acknowledged()) {
    absl::StrAppend(&line, ", acknowledged by ", a.acknowledged_by(), " at ",
                    FormatUtc(a.acknowledged_time(), a.has_acknowledged_time()));
  }
  if (a.cleared()) {
    absl::StrAppend(&line, ", cleared");
    if (a.has_cleared_time()) absl::StrAppend(&line, " at ", FormatUtc(a.cleared_time()));
  }
  if (a.has_revised_time()) {
    absl::StrAppend(&line, ", revised at ", FormatUtc(a.revised_time()));
  }
  if (!a.message().empty()) absl::StrAppend(&line, ": ", a.message());
  return line;
}

int RunAcknowledge(const AlertsOptions& o, const GlobalOptions& global) {
  if (o.spacecraft_id.empty()) return ReportBadArgument(kVerb, "--ack: needs --spacecraft");
  if (*o.ack < 1) return ReportBadArgument(kVerb, absl::StrCat("--ack ", *o.ack, ": must be >= 1"));
  // With a token the service takes the operator's name from it (an empty name); --operator
  // still wins.
  const std::optional<std::string> name = OperatorName(kVerb, o.operator_name, global);
  if (!name.has_value()) return kExitBadArguments;
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;
  esg::v1::AcknowledgeRequest request;
  request.set_spacecraft_id(o.spacecraft_id);
  request.set_sequence(*o.ack);
  request.set_operator_name(*name);
  absl::StatusOr<esg::v1::Alert> alert = client->AcknowledgeAlert(request);
  if (!alert.ok()) return ReportRpcError(kVerb, alert.status(), global);
  if (o.format == OutputFormat::kJson) {
    PrintJson(AlertJson(*alert));
  } else if (o.format == OutputFormat::kCsv) {
    PrintCsv({AlertJson(*alert)}, ProtoCsvColumns(*esg::v1::Alert::descriptor()));
  } else {
    std::printf("acknowledged: %s\n", AlertLine(*alert).c_str());
  }
  return kExitOk;
}

// Alerts read by a reader thread, handed to the main thread (which owns the output and the
// decision to stop).
struct Inbox {
  std::mutex mu;
  std::condition_variable cv;
  std::deque<esg::v1::Alert> alerts;
  bool replayed = false;  // the end-of-replay marker arrived
  bool done = false;
};

int RunList(const AlertsOptions& o, const GlobalOptions& global) {
  esg::v1::AlertSeverity min_severity = esg::v1::ALERT_SEVERITY_UNSPECIFIED;
  if (!o.min_severity.empty()) {
    const std::optional<esg::v1::AlertSeverity> parsed = ParseSeverity(o.min_severity);
    if (!parsed) {
      return ReportBadArgument(kVerb, "--severity '" + o.min_severity +
                                          "': expected INFO, WARNING, DISTRESS or CRITICAL");
    }
    min_severity = *parsed;
  }
  // What --active and --severity let through.
  const auto shown = [&](const esg::v1::Alert& a) {
    if (o.active_only && (a.cleared() || a.has_revised_time())) return false;
    return a.severity() >= min_severity;
  };
  esg::v1::AlertSubscription request;
  request.set_spacecraft_id(o.spacecraft_id);
  absl::Time since = absl::InfinitePast();  // clamped to 0001-01-01: every stored alert
  if (!o.since.empty()) {
    const std::optional<absl::Time> t = TimeOption(kVerb, "--since", o.since);
    if (!t) return kExitBadArguments;
    since = *t;
  }
  *request.mutable_since() = proto_convert::TimeToProto(since);
  request.set_replay_marker(true);
  request.set_include_revised(o.include_revised);
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;

  std::unique_ptr<AlertStream> stream = client->SubscribeAlerts(request);
  Inbox inbox;
  std::thread reader([&] {
    esg::v1::Alert alert;
    while (stream->Read(&alert)) {
      std::lock_guard<std::mutex> lock(inbox.mu);
      if (alert.replay_complete()) {
        inbox.replayed = true;  // not an alert: the stored ones are complete
      } else {
        inbox.alerts.push_back(alert);
      }
      inbox.cv.notify_one();
    }
    std::lock_guard<std::mutex> lock(inbox.mu);
    inbox.done = true;
    inbox.cv.notify_one();
  });

  void (*previous_handler)(int) = SIG_DFL;
  if (o.follow) {
    g_interrupted = 0;
    previous_handler = std::signal(SIGINT, OnInterrupt);
  }
  const std::vector<std::string> csv_columns = ProtoCsvColumns(*esg::v1::Alert::descriptor());
  if (o.follow && o.format == OutputFormat::kCsv) {
    std::printf("%s\n", CsvLine(csv_columns).c_str());
    std::fflush(stdout);
  }
  // Latest state of each alert, in (spacecraft, sequence) order, for the listing.
  std::map<std::pair<std::string, int64_t>, esg::v1::Alert> latest;
  bool cancelled = false;
  for (;;) {
    std::deque<esg::v1::Alert> batch;
    bool done = false;
    bool replayed = false;
    {
      std::unique_lock<std::mutex> lock(inbox.mu);
      // Woken by an alert, the marker or the end of the stream; the timeout only lets --follow
      // notice Ctrl-C.
      inbox.cv.wait_for(lock, std::chrono::milliseconds(100),
                        [&] { return inbox.done || inbox.replayed || !inbox.alerts.empty(); });
      batch.swap(inbox.alerts);
      done = inbox.done;
      replayed = inbox.replayed;
    }
    for (esg::v1::Alert& a : batch) {
      if (!shown(a)) {
        // The latest state decides: an alert cleared since it was read drops out.
        if (!o.follow) latest.erase({a.spacecraft_id(), a.sequence()});
        continue;
      }
      if (o.follow) {
        if (o.format == OutputFormat::kJson) {
          std::printf("%s\n", AlertJson(a).dump().c_str());
        } else if (o.format == OutputFormat::kCsv) {
          std::printf("%s\n", CsvRow(AlertJson(a), csv_columns).c_str());
        } else {
          std::printf("%s\n", AlertLine(a).c_str());
        }
        std::fflush(stdout);
      } else {
        latest[{a.spacecraft_id(), a.sequence()}] = std::move(a);
      }
    }
    if (done) break;
    // Every alert read before the marker is in this batch or an earlier one.
    const bool stop = o.follow ? g_interrupted != 0 : replayed;
    if (stop && !cancelled) {
      cancelled = true;
      stream->Cancel();  // the reader's Read returns false, then done
    }
  }
  reader.join();
  if (o.follow) std::signal(SIGINT, previous_handler);
  const absl::Status status = stream->Finish();
  if (!status.ok() && !(cancelled && absl::IsCancelled(status))) {
    return ReportRpcError(kVerb, status, global);
  }
  if (o.follow) return kExitOk;

  if (o.format == OutputFormat::kJson) {
    Json alerts = Json::array();
    for (const auto& [key, a] : latest) alerts.push_back(AlertJson(a));
    PrintJson(Json{{"alerts", alerts}});
    return kExitOk;
  }
  if (o.format == OutputFormat::kCsv) {
    std::vector<Json> records;
    for (const auto& [key, a] : latest) records.push_back(AlertJson(a));
    PrintCsv(records, csv_columns);
    return kExitOk;
  }
  int active = 0, unacknowledged = 0;
  for (const auto& [key, a] : latest) {
    std::printf("%s\n", AlertLine(a).c_str());
    if (!a.cleared()) ++active;
    if (!a.acknowledged()) ++unacknowledged;
  }
  std::printf("%zu alerts (%d active, %d unacknowledged)\n", latest.size(), active, unacknowledged);
  return kExitOk;
}

}  // namespace

void RegisterAlerts(CLI::App& app, GlobalOptions& global, int* exit_code) {
  auto options = std::make_shared<AlertsOptions>();
  CLI::App* cmd = app.add_subcommand(
      kVerb, "list, follow or acknowledge alerts (SubscribeAlerts, AcknowledgeAlert)");
  cmd->add_option("--spacecraft", options->spacecraft_id, "spacecraft id (default: all)");
  cmd->add_option("--since", options->since,
                  "stored alerts whose latest occurrence is at or after this RFC 3339 time "
                  "(default: all stored)");
  cmd->add_flag("--active", options->active_only,
                "only the alerts not cleared (nor revised by a re-run over a late frame)");
  cmd->add_option("--severity", options->min_severity,
                  "only alerts of this severity or worse: INFO, WARNING, DISTRESS or CRITICAL")
      ->type_name("MIN");
  cmd->add_flag("--include-revised", options->include_revised,
                "also the stored alerts a re-run over a late frame superseded (revised_time set)");
  CLI::Option* follow = cmd->add_flag("--follow", options->follow,
                                      "keep printing alerts as they change, until Ctrl-C");
  cmd->add_option("--ack", options->ack, "acknowledge alert SEQ (needs --spacecraft)")
      ->excludes(follow);
  cmd->add_option("--operator", options->operator_name,
                  "operator name for --ack (default: the token's name with --token, else $USER)");
  AddFormatOption(cmd, &options->format, "with --follow: one JSON object per line");
  cmd->callback([options, &global, exit_code] {
    *exit_code =
        options->ack.has_value() ? RunAcknowledge(*options, global) : RunList(*options, global);
  });
}

}  // namespace esg::client
