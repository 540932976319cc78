"""An OPC UA server for Baton's tests, written with asyncua (FreeOpcUa), a client-independent implementation.

    python3 opcua_server.py PORT

Serves opc.tcp://127.0.0.1:PORT/ with security None, and prints one line per event on stdout: READY, then
CALL <method> <args>, JOB DONE, JOB FAULT, CANCELLED, and WRITE <variable> <value> for every value a client
wrote (status Good). It serves until stdin closes; a line `SET <variable> <value>` on stdin (`true`, `false` or
an integer) writes a variable as the machine would, and is answered `SET <variable> <value>`.

Namespace 2 (urn:baton:test) holds the object `ns=2;s=Cell`:
- Add(a: Int32, b: Int16) -> Int32: answers at once (the types check the agent's conversions).
- Pick(parts: UInt32, speed: Double) -> UInt32: starts a job and answers its number at once. The job resets
  Done and Fault, runs for 0.1 s / speed, then adds `parts` to Count and sets Done; with `parts` = 0 it sets
  Fault instead.
- Refuse(): answers BadInvalidState.
- Hang(): never answers (the test kills the server while the agent waits).
- Stop(): cancels the running job: Busy FALSE, prints CANCELLED.
- StopSlowly(): as a slow PLC does, cancels whatever job runs 0.3 s later, and prints CANCELLED JOB <n>, the
  number of that job.
- Variables Done, Fault, Busy (BOOL), Count (Int32), Lamp (BOOL), Door (BOOL), Setpoint (Int16), all writable.
"""

import asyncio
import sys

from asyncua import Server, ua
from asyncua.common.callback import CallbackType
from asyncua.common.methods import uamethod

JOB_S = 0.1


def say(line):
    print(line, flush=True)


async def main(port):
    server = Server()
    await server.init()
    server.set_endpoint(f"opc.tcp://127.0.0.1:{port}/")
    server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
    idx = await server.register_namespace("urn:baton:test")
    cell = await server.nodes.objects.add_object(ua.NodeId("Cell", idx), ua.QualifiedName("Cell", idx))

    async def variable(name, value, vtype):
        node = await cell.add_variable(ua.NodeId(f"Cell.{name}", idx), ua.QualifiedName(name, idx), value, vtype)
        await node.set_writable()
        return node

    done = await variable("Done", False, ua.VariantType.Boolean)
    fault = await variable("Fault", False, ua.VariantType.Boolean)
    busy = await variable("Busy", False, ua.VariantType.Boolean)
    count = await variable("Count", 0, ua.VariantType.Int32)
    await variable("Lamp", False, ua.VariantType.Boolean)
    await variable("Door", False, ua.VariantType.Boolean)
    await variable("Setpoint", 0, ua.VariantType.Int16)
    names = {}
    for child in await cell.get_children():
        names[child.nodeid] = (await child.read_browse_name()).Name

    def written(event, _dispatcher):
        if not event.is_external:
            return
        for item, result in zip(event.request_params.NodesToWrite, event.response_params):
            if item.AttributeId == ua.AttributeIds.Value and result.is_good():
                say(f"WRITE {names.get(item.NodeId, item.NodeId.to_string())} {item.Value.Value.Value}")

    server.subscribe_server_callback(CallbackType.PostWrite, written)
    state = {"job": None, "jobs": 0}

    @uamethod
    def add(parent, a, b):
        say(f"CALL Add {a} {b}")
        return ua.Variant(a + b, ua.VariantType.Int32)

    async def run_job(parts, speed):
        await asyncio.sleep(JOB_S / max(speed, 1e-6))
        await busy.write_value(False)
        if parts == 0:
            await fault.write_value(True)
            say("JOB FAULT")
        else:
            total = await count.read_value()
            await count.write_value(ua.Variant(total + parts, ua.VariantType.Int32))
            await done.write_value(True)
            say("JOB DONE")

    @uamethod
    async def pick(parent, parts, speed):
        say(f"CALL Pick {parts} {speed}")
        await done.write_value(False)
        await fault.write_value(False)
        await busy.write_value(True)
        state["jobs"] += 1
        state["job"] = asyncio.ensure_future(run_job(parts, speed))
        return ua.Variant(state["jobs"], ua.VariantType.UInt32)

    # Not a `uamethod`: asyncua answers a method's exception with BadUnexpectedError, and a status code returned
    # as it is.
    def refuse(parent):
        say("CALL Refuse")
        return ua.StatusCode(ua.StatusCodes.BadInvalidState)

    @uamethod
    async def hang(parent):
        say("CALL Hang")
        await asyncio.Event().wait()

    @uamethod
    async def stop(parent):
        job = state["job"]
        if job is not None and not job.done():
            job.cancel()
        await busy.write_value(False)
        say("CANCELLED")

    @uamethod
    async def stop_slowly(parent):
        await asyncio.sleep(0.3)
        job = state["job"]
        if job is not None and not job.done():
            job.cancel()
        await busy.write_value(False)
        say(f"CANCELLED JOB {state['jobs']}")

    def arg(name, vtype):
        return ua.Argument(Name=name, DataType=ua.NodeId(vtype.value), ValueRank=-1)

    Int32, Int16, UInt32, Double = (ua.VariantType.Int32, ua.VariantType.Int16, ua.VariantType.UInt32,
                                    ua.VariantType.Double)
    await cell.add_method(ua.NodeId("Cell.Add", idx), ua.QualifiedName("Add", idx), add,
                          [arg("a", Int32), arg("b", Int16)], [arg("sum", Int32)])
    await cell.add_method(ua.NodeId("Cell.Pick", idx), ua.QualifiedName("Pick", idx), pick,
                          [arg("parts", UInt32), arg("speed", Double)], [arg("job", UInt32)])
    await cell.add_method(ua.NodeId("Cell.Refuse", idx), ua.QualifiedName("Refuse", idx), refuse, [], [])
    await cell.add_method(ua.NodeId("Cell.Hang", idx), ua.QualifiedName("Hang", idx), hang, [], [])
    await cell.add_method(ua.NodeId("Cell.Stop", idx), ua.QualifiedName("Stop", idx), stop, [], [])
    await cell.add_method(ua.NodeId("Cell.StopSlowly", idx), ua.QualifiedName("StopSlowly", idx), stop_slowly, [], [])

    types = {"Door": ua.VariantType.Boolean, "Lamp": ua.VariantType.Boolean, "Done": ua.VariantType.Boolean,
             "Fault": ua.VariantType.Boolean, "Busy": ua.VariantType.Boolean, "Count": ua.VariantType.Int32,
             "Setpoint": ua.VariantType.Int16}
    async with server:
        say("READY")
        loop = asyncio.get_running_loop()
        # Serve until stdin closes, so that the server never outlives the test that started it.
        while line := await loop.run_in_executor(None, sys.stdin.readline):
            words = line.split()
            if len(words) != 3 or words[0] != "SET" or words[1] not in types:
                say(f"UNKNOWN COMMAND {line.strip()}")
                continue
            name, text = words[1], words[2]
            value = text.lower() == "true" if types[name] == ua.VariantType.Boolean else int(text)
            node = server.get_node(ua.NodeId(f"Cell.{name}", idx))
            await node.write_value(ua.Variant(value, types[name]))
            say(f"SET {name} {text}")


if __name__ == "__main__":
    asyncio.run(main(int(sys.argv[1])))
