// A C++ user of edm_planner_msgs: fills a CheckInterference request and a PlanElectrodeSet action goal,
// serialises each with rmw_serialize (Fast DDS, through the C++ type support), reads it back with
// rmw_deserialize, and prints one JSON object: per message its CDR bytes (hex), whether the read-back
// message equals the one written, whether the CDR bytes Python wrote for it (a line "name hex" on stdin)
// read back equal to it, and its fields as the C++ introspection type support lists them.
// The Python test fills the same messages and compares (test/test_cpp_typesupport.py). Bytes are not
// compared as such: Fast CDR leaves its alignment padding unwritten, so padding holds whatever was there.
#include <cstdio>
#include <iostream>
#include <map>
#include <string>
#include <vector>

#include "edm_planner_msgs/srv/check_interference.hpp"
#include "edm_planner_msgs/action/plan_electrode_set.hpp"
#include "rcutils/allocator.h"
#include "rmw/error_handling.h"
#include "rmw/rmw.h"
#include "rmw/serialized_message.h"
#include "rosidl_typesupport_cpp/message_type_support.hpp"
#include "rosidl_typesupport_introspection_cpp/identifier.hpp"
#include "rosidl_typesupport_introspection_cpp/message_introspection.hpp"

namespace {

// the CDR bytes Python wrote, by message name (stdin: one "name hex" line each)
std::map<std::string, std::vector<uint8_t>> from_python()
{
  std::map<std::string, std::vector<uint8_t>> out;
  std::string name, digits;
  while (std::cin >> name >> digits) {
    std::vector<uint8_t> & bytes = out[name];
    for (size_t i = 0; i + 1 < digits.size(); i += 2) {
      bytes.push_back(static_cast<uint8_t>(std::stoi(digits.substr(i, 2), nullptr, 16)));
    }
  }
  return out;
}

std::string hex(const rmw_serialized_message_t & s)
{
  static const char digits[] = "0123456789abcdef";
  std::string out;
  for (size_t i = 0; i < s.buffer_length; ++i) {
    out += digits[s.buffer[i] >> 4];
    out += digits[s.buffer[i] & 0xf];
  }
  return out;
}

// {"cdr": "...", "equal": true, "fields": [...]}, or a message on stderr and false
template<typename T>
bool report(const char * name, const T & msg, std::map<std::string, std::vector<uint8_t>> & python, bool last)
{
  const rosidl_message_type_support_t * ts = rosidl_typesupport_cpp::get_message_type_support_handle<T>();
  rmw_serialized_message_t buf = rmw_get_zero_initialized_serialized_message();
  rcutils_allocator_t alloc = rcutils_get_default_allocator();
  if (rmw_serialized_message_init(&buf, 0, &alloc) != RMW_RET_OK ||
    rmw_serialize(&msg, ts, &buf) != RMW_RET_OK)
  {
    std::fprintf(stderr, "%s: rmw_serialize failed: %s\n", name, rmw_get_error_string().str);
    return false;
  }
  T back;
  if (rmw_deserialize(&buf, ts, &back) != RMW_RET_OK) {
    std::fprintf(stderr, "%s: rmw_deserialize failed: %s\n", name, rmw_get_error_string().str);
    return false;
  }
  bool python_equal = false;
  auto written = python.find(name);
  if (written != python.end()) {
    rmw_serialized_message_t theirs = rmw_get_zero_initialized_serialized_message();
    theirs.buffer = written->second.data();
    theirs.buffer_length = theirs.buffer_capacity = written->second.size();
    theirs.allocator = alloc;
    T read;
    python_equal = rmw_deserialize(&theirs, ts, &read) == RMW_RET_OK && read == msg;
  }
  const rosidl_message_type_support_t * intro = get_message_typesupport_handle(
    ts, rosidl_typesupport_introspection_cpp::typesupport_identifier);
  if (intro == nullptr) {
    std::fprintf(stderr, "%s: no introspection type support\n", name);
    return false;
  }
  auto members = static_cast<const rosidl_typesupport_introspection_cpp::MessageMembers *>(intro->data);
  std::printf("\"%s\": {\"cdr\": \"%s\", \"equal\": %s, \"python_equal\": %s, \"fields\": [", name,
    hex(buf).c_str(), back == msg ? "true" : "false", python_equal ? "true" : "false");
  for (uint32_t i = 0; i < members->member_count_; ++i) {
    std::printf("%s\"%s\"", i ? ", " : "", members->members_[i].name_);
  }
  std::printf("]}%s\n", last ? "" : ",");
  return rmw_serialized_message_fini(&buf) == RMW_RET_OK;
}

}  // namespace

int main()
{
  using edm_planner_msgs::srv::CheckInterference;
  CheckInterference::Request req;
  req.geometry_id = "blisk-7";
  req.channel = 3;
  req.electrode_id = "rear";
  req.electrode.discharge_gap = 0.05;
  req.electrode.circumferential_reduction = 0.03;
  req.electrode.reduction_side = "both";
  req.electrode.radial_reduction = 3.0;
  req.electrode.axial_start = -12.5;
  req.electrode.axial_end = 40.25;
  req.electrode.split = "front_rear";
  req.electrode.split_fraction = 0.5;
  req.electrode.split_overlap = 1.0;
  req.method = CheckInterference::Request::METHOD_FAST;
  for (int k = 0; k < 2; ++k) {
    geometry_msgs::msg::Pose p;
    p.position.x = 10.0 + k;
    p.position.y = -2.5 * k;
    p.position.z = 150.125;
    p.orientation.x = 0.0;
    p.orientation.y = 0.6;
    p.orientation.z = 0.0;
    p.orientation.w = 0.8;
    req.poses.push_back(p);
  }
  req.axis_names = {"X", "Y", "Z", "A", "C"};
  for (int k = 0; k < 3; ++k) {
    edm_planner_msgs::msg::AxisPoint a;
    a.positions = {1.0 * k, 2.0, -3.5, 0.1 * k, -0.25};
    req.axis_values.push_back(a);
  }
  req.segments = true;
  req.closest_points = false;
  req.threshold = 0.0125;

  edm_planner_msgs::action::PlanElectrodeSet::Goal goal;
  goal.geometry_id = "rotor37";
  goal.channel = 2;
  goal.tolerance = 0.02;
  goal.max_electrodes = 4;
  goal.write_export = true;
  auto python = from_python();
  std::printf("{\n");
  bool ok = report("check_interference_request", req, python, false);
  ok = report("plan_electrode_set_goal", goal, python, true) && ok;
  std::printf("}\n");
  return ok ? 0 : 1;
}
