"""A DDS-only ROS 2 robot for Baton's tests: a ROS 2 node spoken in plain DDS with Eclipse Cyclone DDS's
Python binding (cyclonedds), as rmw_cyclonedds lays it out - no ROS installation, no Zenoh. Baton reaches it
only through zenoh-bridge-ros2dds.

The node `/robot` has:
- a publisher of `/door` (std_msgs/msg/Bool), publishing the door's state every 100 ms as a sensor driver
  does (`DOOR true` on standard input opens it);
- a subscription to `/lamp` (std_msgs/msg/Bool): prints `LAMP True` for each message;
- a service `/gripper/close` (std_srvs/srv/SetBool): answers success = data, prints `CLOSE True`;
- an action server `/arm/move` (example_interfaces/action/Fibonacci): accepts an order from 0 to 20, sends
  one feedback per number, 50 ms apart, and succeeds; a negative order is rejected, and an order above 20 is a
  sweep that runs until it is cancelled. It prints `GOAL <order>`, `SUCCEEDED`, and `CANCEL` when a goal is
  cancelled.

It announces the node on `ros_discovery_info` with 16-byte GIDs (Iron and later: Jazzy, Kilted), the way the
bridge learns which DDS readers and writers make up which ROS node. Its domain id is its first argument;
CYCLONEDDS_URI keeps it on loopback. It prints `READY` once everything is created, and ends when standard
input closes.
"""

import sys
import threading
import time
from dataclasses import dataclass, field

from cyclonedds.core import Listener, Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, int8, int32, int64, sequence, uint8, uint32, uint64
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

PRINT = threading.Lock()


def say(line):
    with PRINT:
        print(line, flush=True)


# --- message types, named as rmw_cyclonedds names them ---------------------------------------------------


@dataclass
class Bool(IdlStruct, typename="std_msgs::msg::dds_::Bool_"):
    data: bool


# A service's request and reply carry rmw_cyclonedds's header first: the client's GUID and a sequence number.
@dataclass
class SetBoolRequest(IdlStruct, typename="std_srvs::srv::dds_::SetBool_Request_"):
    client_guid: uint64
    sequence: int64
    data: bool


@dataclass
class SetBoolResponse(IdlStruct, typename="std_srvs::srv::dds_::SetBool_Response_"):
    client_guid: uint64
    sequence: int64
    success: bool
    message: str


@dataclass
class UUID(IdlStruct, typename="unique_identifier_msgs::msg::dds_::UUID_"):
    uuid: array[uint8, 16]


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class GoalInfo(IdlStruct, typename="action_msgs::msg::dds_::GoalInfo_"):
    goal_id: UUID
    stamp: Time


@dataclass
class GoalStatus(IdlStruct, typename="action_msgs::msg::dds_::GoalStatus_"):
    goal_info: GoalInfo
    status: int8


@dataclass
class GoalStatusArray(IdlStruct, typename="action_msgs::msg::dds_::GoalStatusArray_"):
    status_list: sequence[GoalStatus]


@dataclass
class FibonacciGoal(IdlStruct, typename="example_interfaces::action::dds_::Fibonacci_Goal_"):
    order: int32


@dataclass
class FibonacciResult(IdlStruct, typename="example_interfaces::action::dds_::Fibonacci_Result_"):
    sequence: sequence[int32]


@dataclass
class FibonacciFeedback(IdlStruct, typename="example_interfaces::action::dds_::Fibonacci_Feedback_"):
    sequence: sequence[int32]


@dataclass
class SendGoalRequest(IdlStruct, typename="example_interfaces::action::dds_::Fibonacci_SendGoal_Request_"):
    client_guid: uint64
    sequence: int64
    goal_id: UUID
    goal: FibonacciGoal


@dataclass
class SendGoalResponse(IdlStruct, typename="example_interfaces::action::dds_::Fibonacci_SendGoal_Response_"):
    client_guid: uint64
    sequence: int64
    accepted: bool
    stamp: Time


@dataclass
class GetResultRequest(IdlStruct, typename="example_interfaces::action::dds_::Fibonacci_GetResult_Request_"):
    client_guid: uint64
    sequence: int64
    goal_id: UUID


@dataclass
class GetResultResponse(IdlStruct, typename="example_interfaces::action::dds_::Fibonacci_GetResult_Response_"):
    client_guid: uint64
    sequence: int64
    status: int8
    result: FibonacciResult


@dataclass
class CancelGoalRequest(IdlStruct, typename="action_msgs::srv::dds_::CancelGoal_Request_"):
    client_guid: uint64
    sequence: int64
    goal_info: GoalInfo


@dataclass
class CancelGoalResponse(IdlStruct, typename="action_msgs::srv::dds_::CancelGoal_Response_"):
    client_guid: uint64
    sequence: int64
    return_code: int8
    goals_canceling: sequence[GoalInfo]


@dataclass
class FeedbackMessage(IdlStruct, typename="example_interfaces::action::dds_::Fibonacci_FeedbackMessage_"):
    goal_id: UUID
    feedback: FibonacciFeedback


@dataclass
class Gid(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
    data: array[uint8, 16]


@dataclass
class NodeEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
    node_namespace: str
    node_name: str
    reader_gid_seq: sequence[Gid]
    writer_gid_seq: sequence[Gid]


@dataclass
class ParticipantEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"):
    gid: Gid
    node_entities_info_seq: sequence[NodeEntitiesInfo]


# --- the node ----------------------------------------------------------------------------------------------

STATUS_EXECUTING, STATUS_SUCCEEDED, STATUS_CANCELED = 2, 4, 5

ROS_QOS = Qos(
    Policy.Reliability.Reliable(duration(seconds=1)),
    Policy.Durability.Volatile,
    Policy.History.KeepLast(10),
)
# Services and action results must not lose a request: rmw_cyclonedds keeps them all.
SERVICE_QOS = Qos(
    Policy.Reliability.Reliable(duration(seconds=1)),
    Policy.Durability.Volatile,
    Policy.History.KeepAll,
)


class Robot:
    def __init__(self, domain):
        self.dp = DomainParticipant(domain)
        self.readers, self.writers = [], []
        self.goals = {}  # goal id bytes -> {"status", "result", "waiting": [(guid, seq)]}
        self.lock = threading.Lock()

        self.door = self.writer("rt/door", Bool, ROS_QOS)
        self.reader("rt/lamp", Bool, ROS_QOS, lambda s: say(f"LAMP {s.data}"))

        self.close_reply = self.writer("rr/gripper/closeReply", SetBoolResponse, SERVICE_QOS)
        self.reader("rq/gripper/closeRequest", SetBoolRequest, SERVICE_QOS, self.on_close)

        base = "arm/move/_action/"
        self.goal_reply = self.writer(f"rr/{base}send_goalReply", SendGoalResponse, SERVICE_QOS)
        self.reader(f"rq/{base}send_goalRequest", SendGoalRequest, SERVICE_QOS, self.on_goal)
        self.result_reply = self.writer(f"rr/{base}get_resultReply", GetResultResponse, SERVICE_QOS)
        self.reader(f"rq/{base}get_resultRequest", GetResultRequest, SERVICE_QOS, self.on_result)
        self.cancel_reply = self.writer(f"rr/{base}cancel_goalReply", CancelGoalResponse, SERVICE_QOS)
        self.reader(f"rq/{base}cancel_goalRequest", CancelGoalRequest, SERVICE_QOS, self.on_cancel)
        self.feedback = self.writer(f"rt/{base}feedback", FeedbackMessage, ROS_QOS)
        self.status = self.writer(
            f"rt/{base}status",
            GoalStatusArray,
            Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.Durability.TransientLocal, Policy.History.KeepLast(1)),
        )

        # The node, announced the way rmw_dds_common does: every reader and writer of it by GID.
        info_qos = Qos(
            Policy.Reliability.Reliable(duration(seconds=1)),
            Policy.Durability.TransientLocal,
            Policy.History.KeepLast(1),
        )
        info = DataWriter(self.dp, Topic(self.dp, "ros_discovery_info", ParticipantEntitiesInfo), qos=info_qos)
        gid = lambda e: Gid(list(e.guid.bytes))
        node = NodeEntitiesInfo("/", "robot", [gid(r) for r in self.readers], [gid(w) for w in self.writers])
        info.write(ParticipantEntitiesInfo(Gid(list(self.dp.guid.bytes)), [node]))
        self.info = info

    def writer(self, name, ty, qos):
        w = DataWriter(self.dp, Topic(self.dp, name, ty), qos=qos)
        self.writers.append(w)
        return w

    def reader(self, name, ty, qos, on_sample):
        def on_data(reader):
            for s in reader.take(N=100):
                if isinstance(s, ty):
                    on_sample(s)

        r = DataReader(self.dp, Topic(self.dp, name, ty), qos=qos, listener=Listener(on_data_available=on_data))
        self.readers.append(r)
        return r

    def on_close(self, req):
        say(f"CLOSE {req.data}")
        message = "closed" if req.data else "refused"
        self.close_reply.write(SetBoolResponse(req.client_guid, req.sequence, req.data, message))

    def on_goal(self, req):
        order = req.goal.order
        key = bytes(req.goal_id.uuid)
        accepted = order >= 0
        say(f"GOAL {order}")
        if accepted:
            with self.lock:
                self.goals[key] = {"status": STATUS_EXECUTING, "result": None, "waiting": []}
        now = time.time()
        self.goal_reply.write(SendGoalResponse(req.client_guid, req.sequence, accepted, Time(int(now), 0)))
        if accepted:
            threading.Thread(target=self.execute, args=(req.goal_id, order), daemon=True).start()

    def execute(self, goal_id, order):
        key = bytes(goal_id.uuid)
        seq = [0, 1]
        i = 1
        while i < order or order > 20:
            time.sleep(0.05)
            with self.lock:
                if self.goals[key]["status"] != STATUS_EXECUTING:
                    return
            seq = (seq + [seq[-1] + seq[-2]])[-20:]
            i += 1
            self.feedback.write(FeedbackMessage(goal_id, FibonacciFeedback(list(seq))))
        self.finish(key, STATUS_SUCCEEDED, seq)
        say("SUCCEEDED")

    def finish(self, key, status, seq):
        with self.lock:
            goal = self.goals[key]
            if goal["status"] != STATUS_EXECUTING:
                return
            goal["status"], goal["result"] = status, list(seq)
            waiting, goal["waiting"] = goal["waiting"], []
        for guid, n in waiting:
            self.result_reply.write(GetResultResponse(guid, n, status, FibonacciResult(list(seq))))

    def on_result(self, req):
        key = bytes(req.goal_id.uuid)
        with self.lock:
            goal = self.goals.get(key)
            if goal is not None and goal["status"] == STATUS_EXECUTING:
                goal["waiting"].append((req.client_guid, req.sequence))
                return
        status, seq = (goal["status"], goal["result"]) if goal else (0, [])
        self.result_reply.write(GetResultResponse(req.client_guid, req.sequence, status, FibonacciResult(seq)))

    def on_cancel(self, req):
        key = bytes(req.goal_info.goal_id.uuid)
        with self.lock:
            goal = self.goals.get(key)
            running = goal is not None and goal["status"] == STATUS_EXECUTING
        say("CANCEL")
        # ERROR_NONE with the goal listed, or GOAL_TERMINATED / UNKNOWN_GOAL.
        code = 0 if running else (3 if goal is not None else 2)
        self.cancel_reply.write(
            CancelGoalResponse(req.client_guid, req.sequence, code, [req.goal_info] if running else [])
        )
        if running:
            self.finish(key, STATUS_CANCELED, [])


def main():
    robot = Robot(int(sys.argv[1]))
    door = [False]

    def sensor():
        while True:
            robot.door.write(Bool(door[0]))
            time.sleep(0.1)

    threading.Thread(target=sensor, daemon=True).start()
    say("READY")
    for line in sys.stdin:
        words = line.split()
        if len(words) == 2 and words[0] == "DOOR":
            door[0] = words[1].lower() == "true"
    # Standard input closed: the test is over.


if __name__ == "__main__":
    main()
