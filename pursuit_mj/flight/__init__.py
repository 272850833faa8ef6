"""Real flights through cflib, and a virtual Crazyflie to rehearse them.

    spec.py, plan.py  the flight file -> a checked FlightPlan (task config, layout, frames,
                      drone order); bad files are refused before any radio is touched
    links.py          cflib links to every drone (opened together, always closed)
    board.py          the latest estimates and health of every drone (StateBoard)
    preflight.py      refuse to take off with a clear reason
    bridge.py         take off -> [estimates -> observations (observe.py, the simulator's
                      code) -> policy -> velocity commands -> safety filters (safety.py)
                      -> radio] at the decision rate -> land
    events.py         every event, timed, in a JSONL log; rerun_log.py: the flight for rerun
    session.py        one whole flight from a flight file (what `pursuit-mj fly` runs)
    align.py          measure the lab -> layout transform; keys.py: emergency-stop keys
    virtual/          Crazyflies that speak cflib's protocol over udp://, backed by
                      pursuit_mj's quadrotor physics

Frames: the *lab* frame is where the positioning system measures (m, z up); the *layout*
frame is the task's (origin at the arena's lower-left corner); `frames.LabTransform` maps
one to the other. Flow-deck drones estimate relative to their own start; `DroneFrames`
maps those estimates into the lab frame.
"""
