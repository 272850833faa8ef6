"""Virtual Crazyflies to rehearse flights: they speak cflib's protocol over udp:// links.

    protocol.py   CRTP numbers, the log and parameter tables, TOC replies with CRC
    firmware.py   one drone's packet handler (params, logs, setpoints, high-level commander,
                  supervisor, emergency stop), as the firmware answers them
    commander.py  the firmware's setpoint rules for all drones at once (priorities,
                  watchdog, high-level trajectories, emergency stop)
    airframe.py   the bodies: pursuit_mj's quadrotor model and controller in a MuJoCo lab
    fleet.py      `VirtualFleet`: sockets, real-time stepping, sensors, battery, faults
"""
