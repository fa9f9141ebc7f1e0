"""mocap_phc: the PHC / PHC+ motion imitator plugin (observations, rewards, termination, env, imitator)."""
