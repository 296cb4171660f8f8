// trackflow bench helper (MIT, part of trackflow): a VRPN tracker client that prints every
// report it receives with full precision, one line each:
//   sec usec sensor px py pz qx qy qz qw
// It is compiled by bench/vrpn_official.py against a VRPN library built from the public
// VRPN sources outside this repository (nothing of VRPN is kept here). VRPN's own warnings
// ("No response from server ...") go to stderr as in every VRPN client.
#include <vrpn_Tracker.h>

#include <cstdio>
#include <cstdlib>

static void VRPN_CALLBACK on_report(void *, const vrpn_TRACKERCB t)
{
    std::printf("%ld %ld %d %.17g %.17g %.17g %.17g %.17g %.17g %.17g\n",
                static_cast<long>(t.msg_time.tv_sec), static_cast<long>(t.msg_time.tv_usec),
                static_cast<int>(t.sensor), t.pos[0], t.pos[1], t.pos[2], t.quat[0], t.quat[1],
                t.quat[2], t.quat[3]);
}

int main(int argc, char **argv)
{
    if (argc != 3) {
        std::fprintf(stderr, "usage: %s DEVICE@HOST:PORT SECONDS\n", argv[0]);
        return 2;
    }
    vrpn_Tracker_Remote tracker(argv[1]);
    tracker.register_change_handler(nullptr, on_report);
    const double seconds = std::atof(argv[2]);
    timeval start, now;
    vrpn_gettimeofday(&start, nullptr);
    do {
        tracker.mainloop();
        vrpn_SleepMsecs(1);
        vrpn_gettimeofday(&now, nullptr);
    } while (vrpn_TimevalDurationSeconds(now, start) < seconds);
    std::fflush(stdout);
    return 0;
}
