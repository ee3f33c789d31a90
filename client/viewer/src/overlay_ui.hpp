// The overlay drawn with Dear ImGui: the overlay's lines, the settings as widgets, the false color's legend.
#pragma once

#include "svo/viewer/overlay.hpp"

namespace svo::viewer {

// What the widgets hold between frames.
struct OverlayWidgets {
  int budgetMiB = 0;  // the budget slider's value until applied (0: the applied budget)
};

// Draws the overlay (inside Window::beginOverlay / endOverlay); returns whether the user changed `settings`.
bool drawOverlay(const OverlayStats& stats, ViewSettings& settings, OverlayWidgets& widgets);

}  // namespace svo::viewer
