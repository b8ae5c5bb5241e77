// reflexarm: the real-time core (umbrella header).
#pragma once

#include "reflexarm/controller.hpp"
#include "reflexarm/fault.hpp"
#include "reflexarm/modal_damping.hpp"
#include "reflexarm/params.hpp"
#include "reflexarm/signals.hpp"
